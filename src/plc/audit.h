/* SPDX-License-Identifier: MIT */
/*
 * audit.h - the audit trail: who commanded the robot, what, and with what
 * outcome.
 *
 * Every command the gateway sends to the robot on a PLC's behalf or its own
 * (the network-exception handler, the policy's pause or stop; not the
 * read-only get_* queries it makes to fill the information registers), and
 * every Modbus write it refuses, is recorded once:
 * - who: the transport ("modbus", "mbaps", or another transport's name),
 *   the client's address and port (or line), and on mbaps the certificate's subject
 *   and role; "gateway" for the gateway's own commands;
 * - what: the command's cmdName and its parameters as sent (a setpoint's
 *   value: {"rate_value":0.5}), or the refused write's table and address
 *   with the command it would have sent ("coil 107 play_program");
 * - the outcome: the result (cmd_outcome_name(), or "refused" with the
 *   Modbus exception), the robot's errorCode and errorMsg, and for a
 *   refusal its reason as the PLC's result registers show it ("motion
 *   off: ...", "fault 1 latched: reset it first",
 *   "outside role ...", "not the write owner ...", "busy: ...").
 * A fault reset is recorded too (command "fault_reset", what the fault).
 * A command is recorded when its result is known (a reply, a timeout, the
 * link lost, or not sent at all).
 *
 * Where the records go (struct audit_sink): under journald, as structured
 * fields (JAKAGW_CLIENT=, JAKAGW_TRANSPORT=, JAKAGW_SUBJECT=, JAKAGW_ROLE=,
 * JAKAGW_COMMAND=, JAKAGW_WHAT=, JAKAGW_RESULT=, JAKAGW_REASON=,
 * JAKAGW_ERROR_CODE=, JAKAGW_ERROR_MSG=, JAKAGW_COUNT=) through sd_journal_send, so that
 * "journalctl -u jakagw JAKAGW_COMMAND=play_program" finds them; elsewhere
 * as one "audit: ..." line on stderr. Frequent records (setpoints and
 * outputs, which send a command on every write, and refused writes) are
 * aggregated per client host (not port), command (or refusal, its exception and reason)
 * and period, whatever the address: the first of a period is recorded at
 * once, the others as one record with their count (JAKAGW_COUNT=) when
 * the period ends, its 'what' the distinct whats they had ("coil 107
 * play_program, coil 200 set_digital_output"; past the field's size,
 * "and N more"). The last AUDIT_LAST records of the PLCs' and of the
 * gateway's own are kept apart for the status page, so that the gateway's
 * retries never push a PLC's command out of view.
 *
 * Time comes through 'struct audit_clock' and output through 'struct
 * audit_sink', so the rules are unit-tested without a loop or a journal.
 */
#ifndef JAKAGW_AUDIT_H
#define JAKAGW_AUDIT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "command.h"
#include "log.h"

#define AUDIT_LAST 32
#define AUDIT_PENDING 160
#define AUDIT_AGGREGATES 256
#define AUDIT_PERIOD_MS 10000

struct audit_who {
    char transport[16];
    char client[72]; /* address:port */
    char subject[128];
    char role[64];
};

struct audit_record {
    uint64_t seq;      /* from 1 */
    uint64_t wall_ms;  /* when recorded, ms since the Unix epoch */
    struct audit_who who;
    char command[48];  /* cmdName, or "write" for a refused write */
    char what[256];    /* parameters; a refused write's "holding register 100+2" */
    char result[24];   /* cmd_outcome_name(), or "refused" */
    long error_code;   /* the robot's errorCode; a refusal's exception */
    char error_msg[128];
    char reason[128];  /* a refusal's; "" */
    unsigned count;    /* records it stands for (aggregated), >= 1 */
};

struct audit_sink {
    /* Writes one record; NULL: audit_default_emit. */
    void (*emit)(void *user, const struct audit_record *r);
    void *user;
};

struct audit_clock {
    uint64_t (*now_ms)(void *user);  /* monotonic */
    uint64_t (*wall_ms)(void *user); /* since the epoch; NULL: the system's */
    void *user;
};

struct audit_pending_cmd {
    const void *key; /* the command's result slot; NULL: free */
    uint64_t order;
    struct audit_who who;
    char command[48];
    char what[256];
    bool frequent;
};

struct audit_aggregate {
    bool used;
    uint64_t since_ms;   /* the period's start */
    struct audit_record first; /* identifies it: who, command, what, result */
    unsigned more;       /* after the first, in this period */
    char whats[256];     /* their distinct whats, ", " between */
    unsigned whats_left; /* distinct whats that found no room */
    bool several_ports;  /* from several connections of one host */
    long last_code;
    char last_msg[128];
};

#define AUDIT_COUNTERS 128

/* Commands by command and result, for jakagw_commands_total; past
 * AUDIT_COUNTERS - 1 pairs, the rest counted as command and result "(other)". */
struct audit_counter {
    char command[48];
    char result[24];
    uint64_t n;
};

struct audit {
    struct audit_sink sink;
    struct audit_clock clock;
    struct audit_who writer; /* the write being judged, if any */
    bool have_writer;
    struct audit_pending_cmd pending[AUDIT_PENDING];
    /* One past the last entry of pending in use: a reply looks for its
     * command among these only, not all AUDIT_PENDING. */
    unsigned pending_top;
    uint64_t order;
    struct audit_aggregate aggregates[AUDIT_AGGREGATES];
    struct audit_ring {
        struct audit_record last[AUDIT_LAST]; /* [next] the oldest */
        unsigned next, count;
    } plc, own; /* the PLCs' records (commands, refusals) and the gateway's */
    uint64_t seq;
    uint64_t recorded; /* records emitted, aggregates counted once */
    /* Every command's result counted (never aggregated), and refused
     * writes by exception code; kept across clear_counters, as Prometheus
     * counters are. */
    struct audit_counter counters[AUDIT_COUNTERS];
    unsigned counter_count;
    uint64_t refused_writes[16];
};

void audit_init(struct audit *a, const struct audit_clock *clock, const struct audit_sink *sink);

/*
 * The Modbus write being judged: commands sent until audit_clear_writer()
 * are that client's. NULL subject or role: "".
 */
void audit_set_writer(struct audit *a, const char *transport, const char *client,
                      const char *subject, const char *role);
void audit_clear_writer(struct audit *a);

/*
 * A command went to the command queue, its result to come through
 * audit_command_done() with the same 'key' (results of one key arrive in
 * the order sent). 'own': the gateway's own command, whoever is writing.
 * 'frequent': a setpoint or output, aggregated.
 */
void audit_command_sent(struct audit *a, const void *key, const char *command, bool own,
                        bool frequent);
/* The same, with what the command carries ("" none). */
void audit_command_sent_what(struct audit *a, const void *key, const char *command,
                             const char *what, bool own, bool frequent);
/* The result of the oldest command sent with 'key'. */
void audit_command_done(struct audit *a, const void *key, const struct cmd_result *r);

/* A write refused with Modbus exception 'exception'; 'what' names it,
 * 'reason' says why. */
void audit_write_refused(struct audit *a, const char *transport, const char *client,
                         const char *subject, const char *role, const char *what,
                         int exception, const char *reason);

/* The writer (audit_set_writer) reset fault 'what' ("1 PLC heartbeat
 * lost"). */
void audit_fault_reset(struct audit *a, const char *what);

/* Ends the aggregation periods that are over. Call every second or so. */
void audit_flush(struct audit *a);
/* Ends every aggregation period now (when stopping). */
void audit_finish(struct audit *a);

/* The last records of the PLCs, oldest first: 'i' from 0 to
 * audit_count() - 1; and of the gateway's own commands. */
unsigned audit_count(const struct audit *a);
const struct audit_record *audit_get(const struct audit *a, unsigned i);
unsigned audit_own_count(const struct audit *a);
const struct audit_record *audit_own_get(const struct audit *a, unsigned i);

/* One audit record as its stderr line, without the "<5>" prefix:
 * "audit: command=... error_msg=..." (docs/metrics.md), escaped once. */
void audit_format_line(const struct audit_record *r, char *out, size_t size);

/* Is stderr journald's (JOURNAL_STREAM names it)? */
bool audit_stderr_is_journal(void);

/* The default sink: journal fields under journald, a stderr line otherwise. */
void audit_default_emit(void *user, const struct audit_record *r);

#endif
