/* SPDX-License-Identifier: MIT */
/*
 * mb_tls.h - the Modbus/TCP Security transport ("mbaps"): TLS under the
 * Modbus server (mb_server.h), through the engine of tls.h.
 *
 * A new connection is pending while its handshake runs: it is not a Modbus
 * client yet (it neither counts toward max_clients nor keeps the policy's
 * "a client is connected" true), and no byte it sends reaches the framer.
 * Handshake work is rationed to one step per turn of the loop, so that a
 * flood of handshakes delays other handshakes, not the clients already
 * served on either port.
 * A pending connection stops reading while it waits for its step, and may
 * hold at most 64 KiB of ciphertext before it (more is a protocol failure):
 * what unauthenticated peers make the gateway hold is bounded.
 * At most 'max_handshakes' run at once; a new connection beyond them is
 * admitted and a pending one closed, by the plain port's rule: the oldest
 * that has sent nothing, else the oldest pending handshake (counted as
 * over_limit, logged at most once a second). Silent sockets, however fast
 * they come back, then only displace one another. A handshake not done
 * within 'handshake_timeout_ms' is closed and counted. A failed handshake
 * (no certificate, another CA, expired, revoked, not TLS, an old version, a
 * renegotiation attempt later on) is counted by reason and logged,
 * rate-limited. A handshake that succeeds gets a log line (the peer, the
 * certificate's subject, its role or why it was not taken, the rights it
 * gives; at most 10 such lines in 10 s, the rest counted in the next) and
 * the connection becomes a client of the server, with the rights its role
 * has: from then on the decrypted stream goes through the server's framing,
 * limits, deadlines and write checks, exactly as on plain TCP. Every close
 * the gateway starts (a bad MBAP header, the idle timeout, an eviction, a
 * stop) sends close_notify first.
 *
 * The context new connections use can be replaced at any time
 * (mb_tls_set_context, on reload); established ones keep theirs.
 */
#ifndef JAKAGW_MB_TLS_H
#define JAKAGW_MB_TLS_H

#include <stdbool.h>
#include <stdint.h>

#include "log.h"
#include "mb_server.h"
#include "tls.h"

struct mb_tls_stats {
    uint64_t handshakes_ok;
    uint64_t failed[TLS_FAIL_COUNT]; /* by reason; [TLS_FAIL_NONE] unused */
    unsigned handshakes;             /* running now */
    unsigned clients;                /* TLS clients served now */
};

struct mb_tls_config {
    uint32_t handshake_timeout_ms;
    unsigned max_handshakes;
    /*
     * The rights of a certificate's role ('role' "" when it has none;
     * 'valid' false when its role extension is not a clean UTF8String).
     * Sets *listed when [roles] names the role.
     */
    uint32_t (*rights_for_role)(void *user, const char *role, bool valid, bool *listed);
    void *user;
};

struct mb_tls {
    struct tls_context *ctx; /* for new connections */
    struct mb_tls_config cfg;
    struct mb_tls_stats stats;
    struct log_ratelimit fail_log;
    struct log_ratelimit limit_log;
    struct log_ratelimit close_log;
    /* The session lines (one per handshake done), rate-limited (mb_tls.c). */
    uint64_t session_window_ms;
    unsigned session_lines;
    uint64_t sessions_unlogged;
    /* Pending handshakes, oldest first (mb_tls.c). */
    struct mb_tls_conn *pending_oldest, *pending_newest;
    /* Where every connection's ciphertext is read into: each read is fed
     * to its connection's engine before anything else runs. */
    uint8_t read_buf[16384];
    /* Handshake steps waiting for their turn of the loop (mb_tls.c). */
    struct mb_tls_steps *steps;
};

/* The transport; its 'state' is a struct mb_tls. */
extern const struct mb_transport mb_transport_tls;

/* Takes over the reference to 'ctx'. Returns 0 or -EINVAL. */
int mb_tls_init(struct mb_tls *t, struct tls_context *ctx, const struct mb_tls_config *cfg);
/* New connections get 'ctx' (its reference taken over). */
void mb_tls_set_context(struct mb_tls *t, struct tls_context *ctx);
/* Drops the context; connections still open keep theirs. */
void mb_tls_free(struct mb_tls *t);
/* Handshakes failed, every reason together. */
uint64_t mb_tls_failed_total(const struct mb_tls_stats *s);

#endif
