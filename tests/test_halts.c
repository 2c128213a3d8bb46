/* SPDX-License-Identifier: MIT */
/*
 * test_halts.c - pausing and stopping are never lost: the motion-enable
 * coil pauses under a latched fault; nothing a timed-out command's callback
 * submits goes to the connection being dropped.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <modbus.h>
#include <stdio.h>
#include <string.h>

#include "command.h"
#include "policy.h"

/* ---- the policy ---- */

#define LIMIT 1000
#define T0 100000

static struct policy p;
static unsigned actions;
static enum policy_action last_action;

static bool record_action(void *user, enum policy_action action, enum policy_fault reason)
{
    (void)user;
    (void)reason;
    actions++;
    last_action = action;
    return true;
}

/*
 * [network_exception] action = keep (flag only): the heartbeat is lost
 * while a program runs, fault 1 latches, nothing is sent (as configured).
 * The PLC then drops the motion-enable coil, which "pauses the program at
 * once" whatever the action: nothing is sent, the robot keeps moving.
 */
static void motion_enable_drop_pauses_while_a_keep_fault_is_latched(void **state)
{
    (void)state;
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = POLICY_KEEP,
                                .watch = POLICY_WATCH_HEARTBEAT, .motion_enable = true,
                                .single_owner = true};
    struct policy_sink sink = {.send_action = record_action};

    policy_init(&p, &cfg, &sink);
    actions = 0;
    policy_motion_enable(&p, T0, true, false);
    policy_heartbeat(&p, T0, 1, "192.0.2.10:5000", 1);
    policy_check(&p, T0 + LIMIT, true); /* heartbeat lost while moving */
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(actions, 0); /* keep: flag only */
    policy_motion_enable(&p, T0 + LIMIT + 10, false, true); /* still moving */
    assert_int_equal(actions, 1);
    assert_int_equal(last_action, POLICY_PAUSE);
}

/* ---- the command queue ---- */

struct fake {
    char sent[8][128];
    unsigned sent_count;
    uint64_t now;
    unsigned restarts;
    unsigned sent_while_condemned; /* sends between a timeout and its restart */
    bool condemned;
};

static struct fake link;
static struct cmd_queue queue;

static int fake_send(void *io, const char *data, size_t size)
{
    struct fake *l = io;
    assert_true(l->sent_count < 8 && size < 128);
    memcpy(l->sent[l->sent_count], data, size);
    l->sent[l->sent_count++][size] = '\0';
    if (l->condemned)
        l->sent_while_condemned++;
    return 0;
}

static uint64_t fake_now(void *io)
{
    return ((struct fake *)io)->now;
}

static void fake_restart(void *io, const char *why)
{
    struct fake *l = io;
    (void)why;
    l->restarts++;
    l->condemned = false;
    cmd_queue_set_connected(&queue, false);
}

static const char *const follow_up = "{\"cmdName\":\"power_off\"}";
static int follow_up_rc = 1;
static enum cmd_outcome follow_up_outcome;

static void follow_up_done(void *user, const struct cmd_result *r)
{
    (void)user;
    follow_up_outcome = r->outcome;
}

/* The first command's owner submits another from its done callback, as
 * plc_commands does after a reply (a refresh), here on a timeout. */
static void first_done(void *user, const struct cmd_result *r)
{
    (void)user;
    assert_int_equal(r->outcome, CMD_TIMEOUT);
    link.condemned = true; /* from here until restart_link */
    follow_up_rc = cmd_queue_submit(&queue, follow_up, strlen(follow_up), follow_up_done, NULL);
}

/*
 * A command times out: its connection is condemned (restarted so that the
 * late reply cannot answer the next command). A command submitted from the
 * timed-out command's done callback is written to that condemned connection
 * anyway, then failed as "link down": the robot may run it, the owner is
 * told it failed.
 */
static void nothing_written_to_a_connection_condemned_by_a_timeout(void **state)
{
    (void)state;
    struct cmd_ops ops = {.send = fake_send, .now_ms = fake_now,
                          .restart_link = fake_restart, .io = &link};
    const char *first = "{\"cmdName\":\"clear_error\"}";

    memset(&link, 0, sizeof(link));
    link.now = 1000;
    cmd_queue_init(&queue, &ops, 500);
    cmd_queue_set_connected(&queue, true);
    assert_int_equal(cmd_queue_submit(&queue, first, strlen(first), first_done, NULL), 0);
    link.now += 500;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 1);
    printf("follow-up: submit rc %d, outcome %s, written to the condemned connection %u "
           "time(s)\n", follow_up_rc, cmd_outcome_name(follow_up_outcome),
           link.sent_while_condemned);
    assert_int_equal(link.sent_while_condemned, 0);
    cmd_queue_free(&queue);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(motion_enable_drop_pauses_while_a_keep_fault_is_latched),
        cmocka_unit_test(nothing_written_to_a_connection_condemned_by_a_timeout),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
