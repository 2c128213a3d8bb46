/* SPDX-License-Identifier: MIT */
/*
 * tls.h - TLS for jakagw's sockets: OpenSSL 3 over memory BIOs.
 *
 * The engine never touches a socket. A connection takes the ciphertext the
 * peer sent (tls_conn_feed), gives the plaintext out (tls_conn_read), takes
 * plaintext to send (tls_conn_write) and gives the ciphertext to write to
 * the socket (tls_conn_take). The caller's event loop moves the bytes, so
 * nothing here blocks and no thread is added. The same engine serves the
 * Modbus/TCP Security listener (server, mutual authentication) and the
 * links to the robot controller (client).
 *
 * A context (struct tls_context) holds what every new connection uses: the
 * protocol versions (TLS 1.2 and 1.3 only), certificate, key, trusted CAs,
 * CRL. It is reference-counted: a reload makes a new one, and connections
 * made with the old one keep it until they close.
 *
 * Server contexts:
 * - the client must present a certificate that chains to 'ca' (and is not
 *   revoked by 'crl', expired or not yet valid), or the handshake fails;
 * - renegotiation and compression are off; session resumption (session
 *   cache and TLS 1.3 tickets) is on;
 * - the client's role is the UTF8String of its certificate's extension
 *   1.3.6.1.4.1.50316.802.1 (Modbus/TCP Security).
 * Client contexts verify the server's certificate against 'ca' (and its
 * name against the host connected to), or pin its SHA-256 fingerprint, or
 * both.
 */
#ifndef JAKAGW_TLS_H
#define JAKAGW_TLS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* The Modbus/TCP Security role extension. */
#define TLS_ROLE_OID "1.3.6.1.4.1.50316.802.1"
#define TLS_ROLE_MAX 64 /* bytes, with the NUL */

/* Why a handshake failed: the counters PLCs read, and the log lines. */
enum tls_failure {
    TLS_FAIL_NONE = 0,
    TLS_FAIL_NO_CERTIFICATE, /* the client sent none */
    TLS_FAIL_UNTRUSTED,      /* not from a trusted CA, bad signature, name */
    TLS_FAIL_EXPIRED,        /* expired or not yet valid */
    TLS_FAIL_REVOKED,        /* in the CRL */
    TLS_FAIL_PROTOCOL,       /* not TLS, an old version, no shared cipher */
    TLS_FAIL_TIMEOUT,        /* not finished in time (the caller's timer) */
    TLS_FAIL_OVER_LIMIT,     /* too many handshakes at once (the caller's) */
    TLS_FAIL_FINGERPRINT,    /* client: the pinned fingerprint differs */
    TLS_FAIL_COUNT
};

/*
 * Checks a role name ('size' bytes at 'name'), as a certificate carries it
 * and [roles] names it: 1 to TLS_ROLE_MAX - 1 bytes of UTF-8, any
 * language, with no space and no control character. NULL when it is one;
 * else why not ("too long", "not valid UTF-8", "has a space or a control
 * character"), in words a log line or an error message can use.
 */
const char *tls_role_name_problem(const char *name, size_t size);

/* "no certificate", "untrusted", ...: for logs. */
const char *tls_failure_name(enum tls_failure f);

struct tls_settings {
    bool server;
    /*
     * Server only: do not ask the client for a certificate ('ca' may then
     * be empty). The simulator's robot ports; never the Modbus listener,
     * whose clients must authenticate.
     */
    bool anonymous_clients;
    /*
     * Files, PEM. Server: certificate, private_key and ca are required,
     * crl optional. Client: ca and/or fingerprint.
     */
    const char *certificate;
    const char *private_key;
    const char *ca;
    const char *crl;
    /* Client: SHA-256 of the server's certificate (DER), 64 hex digits,
     * with or without ':' between bytes; NULL or "": none. */
    const char *fingerprint;
    int min_version; /* 12 (TLS 1.2) or 13 */
    /* How errors name the files: "[tls] certificate", ... */
    const char *certificate_key, *private_key_key, *ca_key, *crl_key, *fingerprint_key;
};

struct tls_context;

/*
 * Builds a context from 's'. Every file is loaded and checked here: the
 * certificate and key parse and match, the key file is readable by its
 * owner only (mode 0600 or 0400: a key readable by other users is refused),
 * the CA file holds at least one certificate, the CRL file at least one
 * CRL. Returns 0 with *out set (one reference), or -EINVAL / -ENOMEM /
 * another negative errno with one line in 'why' that names the key
 * ("[tls] private_key: /etc/...: readable by other users (mode 0644)...").
 */
int tls_context_new(const struct tls_settings *s, struct tls_context **out, char *why,
                    size_t why_size);
void tls_context_ref(struct tls_context *ctx);
void tls_context_unref(struct tls_context *ctx);
/* The context's own certificate subject ("" for a client without one). */
const char *tls_context_subject(const struct tls_context *ctx);

/*
 * Checks a fingerprint's syntax: 0, or -EINVAL with the reason in 'why'.
 */
int tls_parse_fingerprint(const char *text, uint8_t out[32], char *why, size_t why_size);

enum tls_result {
    TLS_OK = 0,      /* done (handshake) */
    TLS_AGAIN = -1,  /* needs more input from the peer */
    TLS_CLOSED = -2, /* the peer sent close_notify */
    TLS_ERROR = -3,  /* failed: tls_conn_failure() says why */
};

struct tls_conn;

/*
 * A connection on 'ctx' (which it references). 'host': client only, the
 * name or address connected to, checked against the server's certificate
 * when the context has a CA (NULL: not checked). NULL when out of memory.
 */
struct tls_conn *tls_conn_new(struct tls_context *ctx, const char *host);
void tls_conn_free(struct tls_conn *c);

/* Takes ciphertext from the peer. 0, or -ENOMEM. */
int tls_conn_feed(struct tls_conn *c, const void *data, size_t size);

/*
 * Advances the handshake with what was fed. TLS_OK once it is complete
 * (and, for a client, the fingerprint pinned matches), TLS_AGAIN while it
 * needs more from the peer, TLS_ERROR when it failed. Either way, the
 * bytes to send (an alert included) wait in tls_conn_take().
 */
int tls_conn_handshake(struct tls_conn *c);

/*
 * Plaintext that arrived, at most 'size' bytes: the count (> 0), TLS_AGAIN
 * when none is complete yet, TLS_CLOSED at the peer's close_notify,
 * TLS_ERROR on a protocol error or a renegotiation attempt.
 */
int tls_conn_read(struct tls_conn *c, void *buf, size_t size);

/* Encrypts 'size' bytes to send (tls_conn_take). 0, or TLS_ERROR. */
int tls_conn_write(struct tls_conn *c, const void *data, size_t size);

/* Queues close_notify (tls_conn_take). */
void tls_conn_close_notify(struct tls_conn *c);

/* Ciphertext waiting for the socket: how many bytes; take them. */
size_t tls_conn_pending(const struct tls_conn *c);
size_t tls_conn_take(struct tls_conn *c, void *buf, size_t size);

/* After TLS_ERROR from the handshake: why, and a line for the log. */
enum tls_failure tls_conn_failure(const struct tls_conn *c, char *why, size_t why_size);

/* After the handshake: the peer certificate's subject (one line, RFC 2253),
 * the role ("" when the certificate carries none; *valid false when the
 * extension is there but not a usable UTF8String), the protocol version
 * ("TLSv1.3"), and whether the session was resumed. */
const char *tls_conn_subject(const struct tls_conn *c);
const char *tls_conn_role(const struct tls_conn *c, bool *valid);
/*
 * Why the certificate's role was not taken ('valid' false above): "not a
 * valid UTF8String", "too long (5000 bytes; at most 63)", ...; "" when it
 * was, or there is none.
 */
const char *tls_conn_role_problem(const struct tls_conn *c);
/* The peer tried to renegotiate (tls_conn_read said TLS_ERROR). */
bool tls_conn_renegotiation_refused(const struct tls_conn *c);
/* Ciphertext fed and not yet taken by the engine, in bytes. */
size_t tls_conn_buffered(const struct tls_conn *c);
const char *tls_conn_version(const struct tls_conn *c);
bool tls_conn_resumed(const struct tls_conn *c);

#endif
