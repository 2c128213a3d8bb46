/* SPDX-License-Identifier: MIT */
/* audit.c - the audit trail (audit.h). */
#include "audit.h"

#include "log.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <systemd/sd-journal.h>
#include <time.h>
#include <unistd.h>

/* A bounded line: what does not fit is dropped, the text stays ended. */
struct strbuf_lite {
    char *out;
    size_t size, used;
};

static void lite_printf(struct strbuf_lite *b, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

static void lite_printf(struct strbuf_lite *b, const char *fmt, ...)
{
    va_list ap;
    if (b->used + 1 >= b->size)
        return;
    va_start(ap, fmt);
    int n = vsnprintf(b->out + b->used, b->size - b->used, fmt, ap);
    va_end(ap);
    if (n > 0)
        b->used = b->used + (size_t)n < b->size ? b->used + (size_t)n : b->size - 1;
}

/* Copies 'in' (NULL: "") into 'out', cut to fit: on every write, so no printf. */
static void copy(char *out, size_t size, const char *in)
{
    size_t n = in ? strnlen(in, size - 1) : 0;
    if (n)
        memcpy(out, in, n);
    out[n] = '\0';
}

static uint64_t system_wall_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000 + (uint64_t)ts.tv_nsec / 1000000;
}

static uint64_t now_ms(const struct audit *a)
{
    return a->clock.now_ms(a->clock.user);
}

void audit_init(struct audit *a, const struct audit_clock *clock, const struct audit_sink *sink)
{
    memset(a, 0, sizeof(*a));
    a->clock = *clock;
    if (sink)
        a->sink = *sink;
    if (!a->sink.emit)
        a->sink.emit = audit_default_emit;
}

void audit_set_writer(struct audit *a, const char *transport, const char *client,
                      const char *subject, const char *role)
{
    if (!a)
        return;
    copy(a->writer.transport, sizeof(a->writer.transport), transport);
    copy(a->writer.client, sizeof(a->writer.client), client);
    copy(a->writer.subject, sizeof(a->writer.subject), subject);
    copy(a->writer.role, sizeof(a->writer.role), role);
    a->have_writer = true;
}

void audit_clear_writer(struct audit *a)
{
    if (!a)
        return;
    a->have_writer = false;
}

/* Emits a record and keeps it among the last ones. */
static void record(struct audit *a, struct audit_record *r)
{
    r->seq = ++a->seq;
    r->wall_ms = a->clock.wall_ms ? a->clock.wall_ms(a->clock.user) : system_wall_ms();
    if (r->count == 0)
        r->count = 1;
    a->recorded++;
    struct audit_ring *ring = strcmp(r->who.transport, "gateway") == 0 ? &a->own : &a->plc;
    ring->last[ring->next] = *r;
    ring->next = (ring->next + 1) % AUDIT_LAST;
    if (ring->count < AUDIT_LAST)
        ring->count++;
    a->sink.emit(a->sink.user, r);
}

/* The length of a client's host: "192.0.2.9:40001" without ":40001". */
static size_t host_length(const char *client)
{
    const char *colon = strrchr(client, ':');
    size_t n = strlen(client);

    if (!colon || colon == client || colon[1] == '\0' ||
        strspn(colon + 1, "0123456789") != strlen(colon + 1))
        return n;
    return (size_t)(colon - client);
}

static bool same_host(const char *x, const char *y)
{
    size_t n = host_length(x);
    return n == host_length(y) && memcmp(x, y, n) == 0;
}

/*
 * The same client host, command and result (and, for a refusal, exception
 * and reason): not the address, so that a client writing all over the map
 * is still one record per period, not one per address; and not the port,
 * so that a PLC opening a connection for each write is too.
 */
static bool same_kind(const struct audit_record *x, const struct audit_record *y)
{
    return strcmp(x->who.transport, y->who.transport) == 0 &&
           same_host(x->who.client, y->who.client) &&
           strcmp(x->who.subject, y->who.subject) == 0 &&
           strcmp(x->command, y->command) == 0 && strcmp(x->result, y->result) == 0 &&
           strcmp(x->reason, y->reason) == 0 && x->error_code == y->error_code;
}

/* Ends aggregate 'g': its count, if any after the first, as one record. */
static void end_aggregate(struct audit *a, struct audit_aggregate *g)
{
    if (g->more) {
        struct audit_record r = g->first;
        r.count = g->more;
        if (g->several_ports)
            r.who.client[host_length(r.who.client)] = '\0';
        /* add_what() left room for the tail. */
        int n = snprintf(r.what, sizeof(r.what), "%s", g->whats);
        if (g->whats_left && n >= 0 && (size_t)n < sizeof(r.what))
            snprintf(r.what + n, sizeof(r.what) - (size_t)n, " and %u more", g->whats_left);
        r.error_code = g->last_code;
        copy(r.error_msg, sizeof(r.error_msg), g->last_msg);
        record(a, &r);
    }
    g->used = false;
}

/* Is 'what' one of the ", "-separated items of 'list'? */
static bool listed(const char *list, const char *what)
{
    size_t n = strlen(what);
    for (const char *p = list; (p = strstr(p, what)) != NULL; p++)
        if ((p == list || (p >= list + 2 && memcmp(p - 2, ", ", 2) == 0)) &&
            (p[n] == '\0' || memcmp(p + n, ", ", 2) == 0))
            return true;
    return false;
}

/* Adds 'what' to the aggregate's distinct whats; "" adds nothing. A what
 * that does not fit is counted, never cut: "and N more" says so. */
static void add_what(struct audit_aggregate *g, const char *what)
{
    size_t used = strlen(g->whats), n = strlen(what);

    if (!n || listed(g->whats, what))
        return;
    /* Room for ", ", the item, and a later " and N more". */
    if (used + 2 + n + 22 >= sizeof(g->whats)) {
        g->whats_left++;
        return;
    }
    if (used) {
        memcpy(g->whats + used, ", ", 2);
        used += 2;
    }
    memcpy(g->whats + used, what, n + 1);
}

/*
 * A frequent record: the first of its kind in a period is recorded now, the
 * others counted until the period ends.
 */
static void aggregate(struct audit *a, struct audit_record *r)
{
    uint64_t now = now_ms(a);
    struct audit_aggregate *free_slot = NULL, *oldest = NULL;

    for (unsigned i = 0; i < AUDIT_AGGREGATES; i++) {
        struct audit_aggregate *g = &a->aggregates[i];
        if (g->used && now - g->since_ms >= AUDIT_PERIOD_MS)
            end_aggregate(a, g);
        if (!g->used) {
            if (!free_slot)
                free_slot = g;
            continue;
        }
        if (same_kind(&g->first, r)) {
            /* A group over several connections names their host only. */
            if (strcmp(g->first.who.client, r->who.client) != 0)
                g->several_ports = true;
            add_what(g, r->what);
            g->more++;
            g->last_code = r->error_code;
            copy(g->last_msg, sizeof(g->last_msg), r->error_msg);
            return;
        }
        if (!oldest || g->since_ms < oldest->since_ms)
            oldest = g;
    }
    if (!free_slot) {
        /* More kinds at once than slots: the oldest period ends early. */
        end_aggregate(a, oldest);
        free_slot = oldest;
    }
    free_slot->used = true;
    free_slot->since_ms = now;
    free_slot->more = 0;
    free_slot->whats[0] = '\0';
    free_slot->whats_left = 0;
    free_slot->several_ports = false;
    record(a, r);
    free_slot->first = *r;
}

void audit_flush(struct audit *a)
{
    if (!a)
        return;
    uint64_t now = now_ms(a);
    for (unsigned i = 0; i < AUDIT_AGGREGATES; i++) {
        struct audit_aggregate *g = &a->aggregates[i];
        if (g->used && now - g->since_ms >= AUDIT_PERIOD_MS)
            end_aggregate(a, g);
    }
}

void audit_finish(struct audit *a)
{
    if (!a)
        return;
    for (unsigned i = 0; i < AUDIT_AGGREGATES; i++)
        if (a->aggregates[i].used)
            end_aggregate(a, &a->aggregates[i]);
}

void audit_command_sent(struct audit *a, const void *key, const char *command, bool own,
                        bool frequent)
{
    audit_command_sent_what(a, key, command, "", own, frequent);
}

void audit_command_sent_what(struct audit *a, const void *key, const char *command,
                             const char *what, bool own, bool frequent)
{
    struct audit_pending_cmd *slot = NULL;

    if (!a)
        return;
    for (unsigned i = 0; i < AUDIT_PENDING && !slot; i++)
        if (!a->pending[i].key)
            slot = &a->pending[i];
    if (!slot) {
        /* Never more pending than the queue holds; should it happen, the
         * oldest is recorded with its outcome unknown, not dropped. */
        slot = &a->pending[0];
        for (unsigned i = 1; i < AUDIT_PENDING; i++)
            if (a->pending[i].order < slot->order)
                slot = &a->pending[i];
        struct cmd_result unknown = {.outcome = CMD_PENDING};
        copy(unknown.error_msg, sizeof(unknown.error_msg), "no longer followed");
        audit_command_done(a, slot->key, &unknown);
    }
    memset(slot, 0, sizeof(*slot));
    slot->key = key;
    unsigned at = (unsigned)(slot - a->pending);
    if (at >= a->pending_top)
        a->pending_top = at + 1;
    slot->order = ++a->order;
    slot->frequent = frequent;
    copy(slot->command, sizeof(slot->command), command);
    copy(slot->what, sizeof(slot->what), what);
    if (own || !a->have_writer)
        copy(slot->who.transport, sizeof(slot->who.transport), "gateway");
    else
        slot->who = a->writer;
}

static void count_command(struct audit *a, const char *command, const char *result)
{
    for (unsigned i = 0; i < a->counter_count; i++) {
        struct audit_counter *c = &a->counters[i];
        if (strcmp(c->command, command) == 0 && strcmp(c->result, result) == 0) {
            c->n++;
            return;
        }
    }
    /* Bounded by the command table times the outcomes, but a JSON
     * mailbox's cmdName is any text: the last slot counts whatever finds
     * no room, as "(other)", so that no named counter counts another's. */
    struct audit_counter *c = &a->counters[a->counter_count < AUDIT_COUNTERS
                                               ? a->counter_count++
                                               : AUDIT_COUNTERS - 1];
    if (a->counter_count == AUDIT_COUNTERS)
        command = result = "(other)";
    if (c->n == 0) {
        copy(c->command, sizeof(c->command), command);
        copy(c->result, sizeof(c->result), result);
    }
    c->n++;
}

void audit_command_done(struct audit *a, const void *key, const struct cmd_result *res)
{
    struct audit_pending_cmd *p = NULL;

    if (!a)
        return;
    for (unsigned i = 0; i < a->pending_top; i++)
        if (a->pending[i].key == key && (!p || a->pending[i].order < p->order))
            p = &a->pending[i];
    if (!p)
        return; /* a command not sent through audit_command_sent */
    struct audit_record r = {.who = p->who, .error_code = res->error_code};
    copy(r.command, sizeof(r.command), p->command);
    copy(r.what, sizeof(r.what), p->what);
    copy(r.result, sizeof(r.result), cmd_outcome_name(res->outcome));
    count_command(a, r.command, r.result);
    copy(r.error_msg, sizeof(r.error_msg), res->error_msg);
    bool frequent = p->frequent;
    p->key = NULL;
    while (a->pending_top > 0 && !a->pending[a->pending_top - 1].key)
        a->pending_top--;
    if (frequent)
        aggregate(a, &r);
    else
        record(a, &r);
}

void audit_write_refused(struct audit *a, const char *transport, const char *client,
                         const char *subject, const char *role, const char *what,
                         int exception, const char *reason)
{
    if (!a)
        return;
    struct audit_record r = {.error_code = exception};
    copy(r.who.transport, sizeof(r.who.transport), transport);
    copy(r.who.client, sizeof(r.who.client), client);
    copy(r.who.subject, sizeof(r.who.subject), subject);
    copy(r.who.role, sizeof(r.who.role), role);
    copy(r.command, sizeof(r.command), "write");
    a->refused_writes[(unsigned)exception & 15]++;
    copy(r.what, sizeof(r.what), what);
    copy(r.result, sizeof(r.result), "refused");
    snprintf(r.error_msg, sizeof(r.error_msg), "Modbus exception %02X", (unsigned)exception);
    copy(r.reason, sizeof(r.reason), reason);
    aggregate(a, &r);
}

void audit_fault_reset(struct audit *a, const char *what)
{
    if (!a)
        return;
    struct audit_record r = {.count = 1};
    if (a->have_writer)
        r.who = a->writer;
    else
        copy(r.who.transport, sizeof(r.who.transport), "gateway");
    copy(r.command, sizeof(r.command), "fault_reset");
    copy(r.what, sizeof(r.what), what);
    copy(r.result, sizeof(r.result), "done");
    record(a, &r);
}

static const struct audit_record *ring_get(const struct audit_ring *ring, unsigned i)
{
    unsigned oldest = (ring->next + AUDIT_LAST - ring->count) % AUDIT_LAST;
    return i < ring->count ? &ring->last[(oldest + i) % AUDIT_LAST] : NULL;
}

unsigned audit_count(const struct audit *a)
{
    return a->plc.count;
}

const struct audit_record *audit_get(const struct audit *a, unsigned i)
{
    return ring_get(&a->plc, i);
}

unsigned audit_own_count(const struct audit *a)
{
    return a->own.count;
}

const struct audit_record *audit_own_get(const struct audit *a, unsigned i)
{
    return ring_get(&a->own, i);
}

bool audit_stderr_is_journal(void)
{
    const char *stream = getenv("JOURNAL_STREAM");
    unsigned long long dev, ino;
    struct stat st;

    if (!stream || sscanf(stream, "%llu:%llu", &dev, &ino) != 2 ||
        fstat(STDERR_FILENO, &st) != 0)
        return false;
    return (unsigned long long)st.st_dev == dev && (unsigned long long)st.st_ino == ino;
}

/*
 * 'in' as the value of a key=value field of the stderr line, escaped once,
 * here, and printed as it is: as it is when it is one plain word
 * (printable ASCII, no space, quote or backslash) and 'quote' is false;
 * else in quotes, with each quote in it as \x22, a backslash as \\, a
 * control byte or a byte that is not UTF-8 as \xNN (log_escape()). Outside
 * text (a certificate's subject, a PLC's JSON cmdName) thus never ends a
 * field or starts another.
 */
static void field(struct strbuf_lite *b, const char *key, const char *in, bool quote)
{
    char esc[6 * 256 + 1];
    for (const char *p = in; *p && !quote; p++)
        quote = *p <= ' ' || *p >= 0x7F || *p == '"' || *p == '\\';
    log_escape(esc, sizeof(esc), in, strlen(in));
    lite_printf(b, " %s=", key);
    if (quote)
        lite_printf(b, "\"");
    for (const char *p = esc; *p; p++) {
        if (*p == '"')
            lite_printf(b, "\\x22");
        else
            lite_printf(b, "%c", *p);
    }
    if (quote)
        lite_printf(b, "\"");
}

void audit_format_line(const struct audit_record *r, char *out, size_t size)
{
    struct strbuf_lite b = {out, size, 0};
    char msg[6 * sizeof(r->error_msg)];

    if (size)
        out[0] = '\0';
    lite_printf(&b, "audit:");
    field(&b, "command", r->command, false);
    field(&b, "what", r->what, true);
    field(&b, "result", r->result, true);
    field(&b, "reason", r->reason, true);
    field(&b, "transport", r->who.transport, false);
    field(&b, "client", r->who.client, false);
    field(&b, "subject", r->who.subject, true);
    field(&b, "role", r->who.role, true);
    lite_printf(&b, " count=%u error_code=%ld", r->count, r->error_code);
    /* The errorMsg last, unquoted, to the end of the line. */
    log_escape(msg, sizeof(msg), r->error_msg, strlen(r->error_msg));
    lite_printf(&b, " error_msg=%s", msg);
}

void audit_default_emit(void *user, const struct audit_record *r)
{
    /* Outside text (an errorMsg, a certificate's subject) as one line. */
    char msg[6 * sizeof(r->error_msg)], subject[6 * sizeof(r->who.subject)];
    char role[6 * sizeof(r->who.role)], client[6 * sizeof(r->who.client)];
    char what[sizeof(r->command) + sizeof(r->what) + 2];
    static int journal = -1;

    (void)user;
    if (journal < 0)
        journal = audit_stderr_is_journal();
    if (journal) {
        /* The journal's fields, escaped: only this path reads them. */
        log_escape(msg, sizeof(msg), r->error_msg, strlen(r->error_msg));
        log_escape(subject, sizeof(subject), r->who.subject, strlen(r->who.subject));
        log_escape(role, sizeof(role), r->who.role, strlen(r->who.role));
        log_escape(client, sizeof(client), r->who.client, strlen(r->who.client));
        snprintf(what, sizeof(what), "%s%s%s", r->command, r->what[0] ? " " : "", r->what);
        int rc = sd_journal_send(
            "MESSAGE=audit: %s by %s %s: %s%s%s%s%s (x%u)", what, r->who.transport, client,
            r->result, r->reason[0] ? ": " : "", r->reason, msg[0] ? ": " : "", msg, r->count,
            "PRIORITY=5", "SYSLOG_IDENTIFIER=jakagw", "JAKAGW_TRANSPORT=%s", r->who.transport,
            "JAKAGW_CLIENT=%s", client, "JAKAGW_SUBJECT=%s", subject, "JAKAGW_ROLE=%s", role,
            "JAKAGW_COMMAND=%s", r->command, "JAKAGW_WHAT=%s", r->what, "JAKAGW_RESULT=%s",
            r->result, "JAKAGW_REASON=%s", r->reason, "JAKAGW_ERROR_CODE=%ld", r->error_code,
            "JAKAGW_ERROR_MSG=%s", msg, "JAKAGW_COUNT=%u", r->count, NULL);
        if (rc == 0)
            return;
    }
    if (!log_enabled(LOG_LEVEL_NOTICE))
        return;
    /* Escaped here, once: not through log_print, which would escape the
     * escapes again (a quote would show as \\x22). */
    char line[LOG_LINE_MAX * 6 + 4];
    audit_format_line(r, line, sizeof(line));
    fprintf(stderr, "<%d>%s\n", (int)LOG_LEVEL_NOTICE, line);
}
