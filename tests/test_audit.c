/* SPDX-License-Identifier: MIT */
/*
 * test_audit.c - the audit trail (audit.h) with a fake clock and a sink
 * that records what would go to the journal: who is recorded for each
 * command, results matched to their command in order, a command recorded
 * once, frequent records aggregated per client and period, the ring of the
 * last records, the command counters, and journald detection.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "audit.h"

#define T0 500000

static uint64_t now;
static struct audit_record emitted[256];
static unsigned emitted_count;
static struct audit a;

static uint64_t fake_now(void *user)
{
    (void)user;
    return now;
}

static uint64_t fake_wall(void *user)
{
    (void)user;
    return 1700000000000ull + now;
}

static void capture(void *user, const struct audit_record *r)
{
    (void)user;
    assert_true(emitted_count < 256);
    emitted[emitted_count++] = *r;
}

static int setup(void **state)
{
    (void)state;
    struct audit_clock clock = {.now_ms = fake_now, .wall_ms = fake_wall};
    struct audit_sink sink = {.emit = capture};
    now = T0;
    emitted_count = 0;
    audit_init(&a, &clock, &sink);
    return 0;
}

static struct cmd_result result(enum cmd_outcome outcome, long code, const char *msg)
{
    struct cmd_result r = {.outcome = outcome, .error_code = code};
    snprintf(r.error_msg, sizeof(r.error_msg), "%s", msg);
    return r;
}

static const int slot_power, slot_output, slot_play;

static void command_is_recorded_once_with_who_and_result(void **state)
{
    (void)state;
    audit_set_writer(&a, "mbaps", "192.0.2.7", "CN=plc-7", "operator");
    audit_command_sent(&a, &slot_power, "power_on", false, false);
    audit_clear_writer(&a);
    assert_int_equal(emitted_count, 0); /* recorded with its result */
    struct cmd_result r = result(CMD_ROBOT_ERROR, 2, "<b>collision</b>");
    audit_command_done(&a, &slot_power, &r);
    assert_int_equal(emitted_count, 1);
    const struct audit_record *e = &emitted[0];
    assert_string_equal(e->who.transport, "mbaps");
    assert_string_equal(e->who.client, "192.0.2.7");
    assert_string_equal(e->who.subject, "CN=plc-7");
    assert_string_equal(e->who.role, "operator");
    assert_string_equal(e->command, "power_on");
    assert_string_equal(e->result, "robot error");
    assert_int_equal(e->error_code, 2);
    assert_string_equal(e->error_msg, "<b>collision</b>");
    assert_int_equal(e->count, 1);
    assert_int_equal(e->wall_ms, 1700000000000ull + T0);
    /* A second result for the same key matches nothing: recorded once. */
    audit_command_done(&a, &slot_power, &r);
    assert_int_equal(emitted_count, 1);
}

static void gateway_commands_and_no_writer_are_the_gateways(void **state)
{
    (void)state;
    audit_set_writer(&a, "modbus", "192.0.2.8", "", "");
    audit_command_sent(&a, &slot_play, "pause_program", true, false); /* the policy's */
    audit_clear_writer(&a);
    audit_command_sent(&a, &slot_power, "set_network_exception_handle", false, false);
    struct cmd_result done = result(CMD_DONE, 0, "");
    audit_command_done(&a, &slot_play, &done);
    audit_command_done(&a, &slot_power, &done);
    assert_int_equal(emitted_count, 2);
    assert_string_equal(emitted[0].who.transport, "gateway");
    assert_string_equal(emitted[0].who.client, "");
    assert_string_equal(emitted[1].who.transport, "gateway");
}

static void results_match_their_commands_in_order(void **state)
{
    (void)state;
    audit_set_writer(&a, "modbus", "192.0.2.1", "", "");
    audit_command_sent(&a, &slot_play, "play_program", false, false);
    audit_set_writer(&a, "modbus", "192.0.2.2", "", "");
    audit_command_sent(&a, &slot_play, "play_program", false, false);
    audit_clear_writer(&a);
    struct cmd_result first = result(CMD_DONE, 0, "");
    struct cmd_result second = result(CMD_TIMEOUT, 0, "no reply");
    audit_command_done(&a, &slot_play, &first);
    audit_command_done(&a, &slot_play, &second);
    assert_int_equal(emitted_count, 2);
    assert_string_equal(emitted[0].who.client, "192.0.2.1");
    assert_string_equal(emitted[0].result, "done");
    assert_string_equal(emitted[1].who.client, "192.0.2.2");
    assert_string_equal(emitted[1].result, "timeout");
}

static void frequent_commands_are_aggregated_per_client_and_period(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    for (unsigned i = 0; i < 50; i++) {
        audit_set_writer(&a, "modbus", i % 2 ? "192.0.2.1" : "192.0.2.2", "", "");
        audit_command_sent(&a, &slot_output, "set_digital_output", false, true);
        audit_clear_writer(&a);
        audit_command_done(&a, &slot_output, &done);
        now += 10;
    }
    /* The first of each client at once, the rest held. */
    assert_int_equal(emitted_count, 2);
    assert_int_equal(emitted[0].count + emitted[1].count, 2);
    audit_flush(&a);
    assert_int_equal(emitted_count, 2); /* the period is not over */
    now = T0 + 10 + AUDIT_PERIOD_MS; /* both periods over */
    audit_flush(&a);
    assert_int_equal(emitted_count, 4);
    assert_int_equal(emitted[2].count + emitted[3].count, 48);
    assert_string_not_equal(emitted[2].who.client, emitted[3].who.client);
    /* A new period starts with a record at once again. */
    audit_set_writer(&a, "modbus", "192.0.2.1", "", "");
    audit_command_sent(&a, &slot_output, "set_digital_output", false, true);
    audit_clear_writer(&a);
    audit_command_done(&a, &slot_output, &done);
    assert_int_equal(emitted_count, 5);
    assert_int_equal(emitted[4].count, 1);
}

static void a_failure_among_frequent_ones_is_its_own_record(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    struct cmd_result down = result(CMD_LINK_DOWN, 0, "link lost");
    audit_set_writer(&a, "modbus", "192.0.2.1", "", "");
    audit_command_sent(&a, &slot_output, "set_digital_output", false, true);
    audit_command_sent(&a, &slot_output, "set_digital_output", false, true);
    audit_command_sent(&a, &slot_output, "set_digital_output", false, true);
    audit_clear_writer(&a);
    audit_command_done(&a, &slot_output, &done);
    audit_command_done(&a, &slot_output, &down);
    audit_command_done(&a, &slot_output, &done);
    assert_int_equal(emitted_count, 2);
    assert_string_equal(emitted[1].result, "link down");
    audit_finish(&a);
    assert_int_equal(emitted_count, 3);
    assert_string_equal(emitted[2].result, "done");
    assert_int_equal(emitted[2].count, 1);
}

static void refused_writes_are_aggregated_and_counted(void **state)
{
    (void)state;
    for (unsigned i = 0; i < 30; i++)
        audit_write_refused(&a, "modbus", "192.0.2.9", "", "", "coil 105", 1, "motion is off");
    audit_write_refused(&a, "modbus", "192.0.2.9", "", "", "holding register 0", 2,
                        "no such address in the register map");
    assert_int_equal(emitted_count, 2);
    assert_string_equal(emitted[0].command, "write");
    assert_string_equal(emitted[0].what, "coil 105");
    assert_string_equal(emitted[0].result, "refused");
    assert_int_equal(emitted[0].error_code, 1);
    assert_string_equal(emitted[0].reason, "motion is off");
    assert_string_equal(emitted[1].what, "holding register 0");
    assert_string_equal(emitted[1].reason, "no such address in the register map");
    assert_int_equal(emitted[1].error_code, 2);
    /* A client writing all over the map: still one record per period. */
    char what[32];
    for (unsigned i = 0; i < 1000; i++) {
        snprintf(what, sizeof(what), "holding register %u", 1000 + i);
        audit_write_refused(&a, "modbus", "192.0.2.9", "", "", what, 1, "motion is off");
    }
    assert_int_equal(emitted_count, 2);
    audit_finish(&a);
    assert_int_equal(emitted_count, 3);
    assert_int_equal(emitted[2].count, 1029);
    /* As many distinct addresses as fit, then how many more: never cut. */
    assert_memory_equal(emitted[2].what, "coil 105, holding register 1000, holding register 1001",
                        54);
    const char *tail = strstr(emitted[2].what, " and ");
    assert_non_null(tail);
    unsigned listed = 1, more = 0;
    for (const char *p = emitted[2].what; p < tail; p++)
        listed += *p == ',';
    assert_int_equal(sscanf(tail, " and %u more", &more), 1);
    assert_int_equal(listed + more, 1001);
    assert_int_equal(a.refused_writes[1], 1030);
    assert_int_equal(a.refused_writes[2], 1);
}

/*
 * The review's case: a resume, a joint_move and three outputs refused
 * within one period, for one reason: the group names each of them; a
 * group of one names its one.
 */
static void refused_groups_name_their_commands_and_addresses(void **state)
{
    (void)state;
    const char *why = "network-exception fault 1 latched: reset it first";
    audit_write_refused(&a, "modbus", "192.0.2.9:5020", "", "", "coil 109 resume_program", 1,
                        why);
    audit_write_refused(&a, "modbus", "192.0.2.9:5020", "", "", "coil 109 resume_program", 1,
                        why);
    audit_write_refused(&a, "modbus", "192.0.2.9:5020", "", "", "holding register 300 joint_move",
                        1, why);
    for (unsigned i = 0; i < 3; i++) {
        char what[64];
        snprintf(what, sizeof(what), "coil %u set_digital_output", 200 + i);
        audit_write_refused(&a, "modbus", "192.0.2.9:5020", "", "", what, 1, why);
    }
    /* Another reason is another group: a group of one. */
    audit_write_refused(&a, "modbus", "192.0.2.9:5020", "", "", "coil 107 play_program", 1,
                        "motion enable is 0");
    audit_write_refused(&a, "modbus", "192.0.2.9:5020", "", "", "coil 107 play_program", 1,
                        "motion enable is 0");
    assert_int_equal(emitted_count, 2);
    audit_finish(&a);
    assert_int_equal(emitted_count, 4);
    const struct audit_record *g = &emitted[2], *one = &emitted[3];
    if (strcmp(g->reason, why) != 0) {
        g = &emitted[3];
        one = &emitted[2];
    }
    assert_string_equal(g->reason, why);
    assert_string_equal(g->who.client, "192.0.2.9:5020");
    assert_int_equal(g->count, 5);
    assert_string_equal(g->what, "coil 109 resume_program, holding register 300 joint_move, "
                                 "coil 200 set_digital_output, coil 201 set_digital_output, "
                                 "coil 202 set_digital_output");
    assert_string_equal(one->reason, "motion enable is 0");
    assert_int_equal(one->count, 1);
    assert_string_equal(one->what, "coil 107 play_program");
}

/* A setpoint's value is part of its record; a fault reset is recorded
 * with who reset it. */
static void setpoint_values_and_fault_resets_are_recorded(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    audit_set_writer(&a, "modbus", "192.0.2.1:40000", "", "");
    audit_command_sent_what(&a, &slot_output, "rapid_rate", "{\"rate_value\":0.5}", false, true);
    audit_command_sent_what(&a, &slot_output, "rapid_rate", "{\"rate_value\":0.8}", false, true);
    audit_command_sent_what(&a, &slot_output, "rapid_rate", "{\"rate_value\":0.8}", false, true);
    audit_fault_reset(&a, "fault 1 (PLC heartbeat lost)");
    audit_clear_writer(&a);
    for (unsigned i = 0; i < 3; i++)
        audit_command_done(&a, &slot_output, &done);
    audit_finish(&a);
    assert_int_equal(emitted_count, 3);
    assert_string_equal(emitted[0].command, "fault_reset");
    assert_string_equal(emitted[0].what, "fault 1 (PLC heartbeat lost)");
    assert_string_equal(emitted[0].who.client, "192.0.2.1:40000");
    assert_string_equal(emitted[0].result, "done");
    assert_string_equal(emitted[1].what, "{\"rate_value\":0.5}");
    assert_int_equal(emitted[2].count, 2);
    assert_string_equal(emitted[2].what, "{\"rate_value\":0.8}");
}

/* The gateway's own commands are kept apart: they never push a PLC's out
 * of the page's view. */
static void own_commands_are_kept_apart_from_the_plcs(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    audit_set_writer(&a, "modbus", "192.0.2.1:40000", "", "");
    audit_command_sent(&a, &slot_play, "play_program", false, false);
    audit_clear_writer(&a);
    audit_command_done(&a, &slot_play, &done);
    for (unsigned i = 0; i < 2 * AUDIT_LAST; i++) {
        audit_command_sent(&a, &slot_power, "set_network_exception_handle", true, false);
        audit_command_done(&a, &slot_power, &done);
    }
    assert_int_equal(audit_count(&a), 1);
    assert_string_equal(audit_get(&a, 0)->command, "play_program");
    assert_int_equal(audit_own_count(&a), AUDIT_LAST);
    assert_string_equal(audit_own_get(&a, 0)->who.transport, "gateway");
}

static void counters_count_every_command_even_aggregated(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    struct cmd_result err = result(CMD_ROBOT_ERROR, -1, "");
    for (unsigned i = 0; i < 20; i++) {
        audit_command_sent(&a, &slot_output, "set_digital_output", false, true);
        audit_command_done(&a, &slot_output, i == 7 ? &err : &done);
    }
    assert_int_equal(a.counter_count, 2);
    assert_string_equal(a.counters[0].command, "set_digital_output");
    assert_string_equal(a.counters[0].result, "done");
    assert_int_equal(a.counters[0].n, 19);
    assert_string_equal(a.counters[1].result, "robot error");
    assert_int_equal(a.counters[1].n, 1);
}

/*
 * More (command, result) pairs than counters (a PLC's JSON mailbox sends
 * any cmdName): each named counter counts only its own, the rest one
 * "(other)" counter, never a named one.
 */
static void counters_past_their_room_count_as_other(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    char name[32];
    for (unsigned i = 0; i < AUDIT_COUNTERS + 50; i++) {
        snprintf(name, sizeof(name), "cmd_%u", i);
        audit_command_sent(&a, &slot_play, name, false, false);
        audit_command_done(&a, &slot_play, &done);
    }
    audit_command_sent(&a, &slot_play, "cmd_0", false, false);
    audit_command_done(&a, &slot_play, &done);
    assert_int_equal(a.counter_count, AUDIT_COUNTERS);
    uint64_t total = 0;
    for (unsigned i = 0; i < AUDIT_COUNTERS - 1; i++) {
        snprintf(name, sizeof(name), "cmd_%u", i);
        assert_string_equal(a.counters[i].command, name);
        assert_int_equal(a.counters[i].n, i == 0 ? 2 : 1);
        total += a.counters[i].n;
    }
    const struct audit_counter *other = &a.counters[AUDIT_COUNTERS - 1];
    assert_string_equal(other->command, "(other)");
    assert_string_equal(other->result, "(other)");
    assert_int_equal(other->n, 51);
    assert_int_equal(total + other->n, AUDIT_COUNTERS + 51);
}

static void the_last_records_are_kept_oldest_first(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    char name[32];
    audit_set_writer(&a, "modbus", "192.0.2.1:40000", "", "");
    for (unsigned i = 0; i < AUDIT_LAST + 5; i++) {
        snprintf(name, sizeof(name), "command_%u", i);
        audit_command_sent(&a, &slot_play, name, false, false);
        audit_command_done(&a, &slot_play, &done);
    }
    assert_int_equal(audit_count(&a), AUDIT_LAST);
    assert_string_equal(audit_get(&a, 0)->command, "command_5");
    assert_string_equal(audit_get(&a, AUDIT_LAST - 1)->command, "command_36");
    assert_null(audit_get(&a, AUDIT_LAST));
    assert_int_equal(audit_get(&a, 0)->seq + AUDIT_LAST - 1, audit_get(&a, AUDIT_LAST - 1)->seq);
}

static void more_pending_than_room_records_the_oldest_as_unknown(void **state)
{
    (void)state;
    static const int keys[AUDIT_PENDING + 1];
    for (unsigned i = 0; i <= AUDIT_PENDING; i++)
        audit_command_sent(&a, &keys[i], "get_data", false, false);
    assert_int_equal(emitted_count, 1);
    assert_string_equal(emitted[0].result, "pending");
    assert_string_equal(emitted[0].error_msg, "no longer followed");
}

static void null_audit_is_harmless(void **state)
{
    (void)state;
    struct cmd_result done = result(CMD_DONE, 0, "");
    audit_set_writer(NULL, "modbus", "x", NULL, NULL);
    audit_command_sent(NULL, &slot_play, "play_program", false, false);
    audit_command_done(NULL, &slot_play, &done);
    audit_write_refused(NULL, "modbus", "x", NULL, NULL, "coil 1", 1, NULL);
    audit_fault_reset(NULL, "fault 1");
    audit_flush(NULL);
    audit_finish(NULL);
}

static void journal_is_detected_from_journal_stream(void **state)
{
    (void)state;
    struct stat st;
    char value[64];
    assert_int_equal(fstat(STDERR_FILENO, &st), 0);
    unsetenv("JOURNAL_STREAM");
    assert_false(audit_stderr_is_journal());
    snprintf(value, sizeof(value), "%llu:%llu", (unsigned long long)st.st_dev,
             (unsigned long long)st.st_ino);
    setenv("JOURNAL_STREAM", value, 1);
    assert_true(audit_stderr_is_journal());
    /* Inherited by a process whose stderr went elsewhere: not the journal. */
    snprintf(value, sizeof(value), "%llu:%llu", (unsigned long long)st.st_dev,
             (unsigned long long)st.st_ino + 1);
    setenv("JOURNAL_STREAM", value, 1);
    assert_false(audit_stderr_is_journal());
    setenv("JOURNAL_STREAM", "garbage", 1);
    assert_false(audit_stderr_is_journal());
    unsetenv("JOURNAL_STREAM");
}

/* The stderr line of a record, as audit_default_emit writes it. */
static void stderr_line(const struct audit_record *r, char *line, size_t size)
{
    FILE *f = tmpfile();
    assert_non_null(f);
    int saved = dup(STDERR_FILENO);
    unsetenv("JOURNAL_STREAM");
    fflush(stderr);
    dup2(fileno(f), STDERR_FILENO);
    audit_default_emit(NULL, r);
    fflush(stderr);
    dup2(saved, STDERR_FILENO);
    close(saved);
    rewind(f);
    assert_non_null(fgets(line, (int)size, f));
    fclose(f);
}

/*
 * Text from outside (a certificate's subject and role, a PLC's JSON
 * cmdName) cannot make up fields of the stderr line: a quote in it is no
 * field's end, a space in an unquoted value no field's start.
 */
static void outside_text_cannot_forge_fields_of_the_line(void **state)
{
    (void)state;
    struct audit_record r = {.count = 1, .error_code = 1};
    snprintf(r.who.transport, sizeof(r.who.transport), "mbaps");
    snprintf(r.who.client, sizeof(r.who.client), "10.0.0.9");
    snprintf(r.who.subject, sizeof(r.who.subject), "CN=plc\" role=\"admin");
    snprintf(r.who.role, sizeof(r.who.role), "monitor");
    snprintf(r.command, sizeof(r.command), "x transport=gateway");
    snprintf(r.result, sizeof(r.result), "refused");
    char line[2048];
    stderr_line(&r, line, sizeof(line));
    assert_non_null(strstr(line, "audit: command=\"x transport=gateway\" what="));
    assert_null(strstr(line, " role=\"admin"));
    assert_non_null(strstr(line, " transport=mbaps "));
    assert_non_null(strstr(line, " role=\"monitor\" "));
    /* The quotes of what, result, reason, subject, role and the command's. */
    unsigned quotes = 0;
    for (const char *p = line; *p; p++)
        quotes += *p == '"';
    assert_int_equal(quotes, 12);
    /* A plain command name stays as it was. */
    snprintf(r.command, sizeof(r.command), "power_on");
    snprintf(r.who.subject, sizeof(r.who.subject), "CN=plc-1");
    stderr_line(&r, line, sizeof(line));
    assert_non_null(strstr(line, "audit: command=power_on what=\"\" result=\"refused\" "
                                 "reason=\"\" transport=mbaps client=10.0.0.9 "
                                 "subject=\"CN=plc-1\" role=\"monitor\" count=1 error_code=1 "
                                 "error_msg="));
}

/*
 * One escaping pass, as docs/metrics.md shows it: a quote is \x22 (not
 * \\x22), a backslash \\, a control byte \xNN; the errorMsg too.
 */
static void the_line_is_escaped_once(void **state)
{
    (void)state;
    struct audit_record r = {.count = 2, .error_code = 1};
    snprintf(r.who.transport, sizeof(r.who.transport), "mbaps");
    snprintf(r.who.client, sizeof(r.who.client), "10.0.0.9:40001");
    snprintf(r.who.subject, sizeof(r.who.subject), "CN=a\"b\\c\001d");
    snprintf(r.command, sizeof(r.command), "write");
    snprintf(r.what, sizeof(r.what), "coil 107 play_program");
    snprintf(r.result, sizeof(r.result), "refused");
    snprintf(r.reason, sizeof(r.reason), "motion is off");
    snprintf(r.error_msg, sizeof(r.error_msg), "bad \"x\" \\ \002");
    char line[2048], formatted[2048];
    stderr_line(&r, line, sizeof(line));
    assert_string_equal(line,
                        "<5>audit: command=write what=\"coil 107 play_program\" "
                        "result=\"refused\" reason=\"motion is off\" transport=mbaps "
                        "client=10.0.0.9:40001 subject=\"CN=a\\x22b\\\\c\\x01d\" role=\"\" "
                        "count=2 error_code=1 error_msg=bad \"x\" \\\\ \\x02\n");
    audit_format_line(&r, formatted, sizeof(formatted));
    assert_memory_equal(line + 3, formatted, strlen(formatted));
}

/*
 * A PLC that opens a connection for each write (many PLC function blocks
 * do) has a new port every time: its refusals are still one kind, so that
 * hammering a refused write costs one record at once and one at the end of
 * the period, not one a write (200 records in 20 s before: the client's
 * port, added for the audit, made each connection a kind of its own). The
 * group names the host without a port, since it spans several.
 */
static void refusals_from_new_ports_of_one_host_are_one_kind(void **state)
{
    (void)state;
    char client[32];
    for (unsigned i = 0; i < 200; i++) {
        snprintf(client, sizeof(client), "192.0.2.9:%u", 40000 + i);
        audit_write_refused(&a, "modbus", client, "", "", "coil 107 play_program", 1,
                            "motion is off");
        now += 100;
    }
    /* An IPv6 peer, "host:port" too, and another host: kinds of their own. */
    audit_write_refused(&a, "modbus", "2001:db8::9:40000", "", "", "coil 107", 1, "x");
    audit_write_refused(&a, "modbus", "2001:db8::9:40001", "", "", "coil 107", 1, "x");
    audit_write_refused(&a, "modbus", "2001:db8::9:40002", "", "", "coil 107", 1, "x");
    audit_write_refused(&a, "modbus", "192.0.2.10:40000", "", "", "coil 107", 1, "x");
    audit_finish(&a);
    /* 192.0.2.9: two periods of a first and a group; the IPv6 host a first
     * and a group of two; 192.0.2.10 one. */
    assert_int_equal(emitted_count, 7);
    assert_string_equal(emitted[0].who.client, "192.0.2.9:40000");
    assert_int_equal(emitted[0].count, 1);
    unsigned total = 0;
    for (unsigned i = 0; i < emitted_count; i++)
        if (strncmp(emitted[i].who.client, "192.0.2.9", 9) == 0)
            total += emitted[i].count;
    assert_int_equal(total, 200);
    assert_string_equal(emitted[1].who.client, "192.0.2.9");
    assert_int_equal(emitted[1].count, 99);
    assert_string_equal(emitted[3].who.client, "192.0.2.9");
    assert_string_equal(emitted[6].who.client, "2001:db8::9");
    assert_int_equal(emitted[6].count, 2);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(command_is_recorded_once_with_who_and_result, setup),
        cmocka_unit_test_setup(gateway_commands_and_no_writer_are_the_gateways, setup),
        cmocka_unit_test_setup(results_match_their_commands_in_order, setup),
        cmocka_unit_test_setup(frequent_commands_are_aggregated_per_client_and_period, setup),
        cmocka_unit_test_setup(a_failure_among_frequent_ones_is_its_own_record, setup),
        cmocka_unit_test_setup(refused_writes_are_aggregated_and_counted, setup),
        cmocka_unit_test_setup(refused_groups_name_their_commands_and_addresses, setup),
        cmocka_unit_test_setup(setpoint_values_and_fault_resets_are_recorded, setup),
        cmocka_unit_test_setup(own_commands_are_kept_apart_from_the_plcs, setup),
        cmocka_unit_test_setup(counters_count_every_command_even_aggregated, setup),
        cmocka_unit_test_setup(counters_past_their_room_count_as_other, setup),
        cmocka_unit_test_setup(the_last_records_are_kept_oldest_first, setup),
        cmocka_unit_test_setup(more_pending_than_room_records_the_oldest_as_unknown, setup),
        cmocka_unit_test_setup(null_audit_is_harmless, setup),
        cmocka_unit_test_setup(refusals_from_new_ports_of_one_host_are_one_kind, setup),
        cmocka_unit_test(journal_is_detected_from_journal_stream),
        cmocka_unit_test(outside_text_cannot_forge_fields_of_the_line),
        cmocka_unit_test(the_line_is_escaped_once),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
