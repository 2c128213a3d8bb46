/* SPDX-License-Identifier: MIT */
/*
 * test_policy.c - the network-exception policy's state machine (policy.h)
 * over every transition, with time given as arguments and the action
 * recorded by a fake sink: the heartbeat watch, the connection watch, both,
 * the motion-enable coil (a level), starts the status cannot show yet, the
 * command gate, the latch and its reset, the write owner and the fault's
 * age; the action chosen for what the arm does (a move outside a program
 * is stopped, never paused), the check of the action against the status
 * after its reply and its one escalation, and a property test over
 * generated faults (POLICY_PROPERTY_SEED replays a run).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <modbus.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "policy.h"
#include "property.h"

#define LIMIT 1000 /* time_limit_ms of every test */
#define T0 100000  /* a clock that does not start at 0 */
#define MOVING true
#define IDLE false
#define PLC_A 1
#define PLC_B 2
#define ADDR_A "192.0.2.10:50001"
#define ADDR_B "192.0.2.11:50002"

struct sink_record {
    unsigned calls;
    enum policy_action action[8];
    enum policy_fault reason[8];
};

static struct policy p;
static struct sink_record sent;

static bool record_action(void *user, enum policy_action action, enum policy_fault reason)
{
    struct sink_record *r = user;
    assert_true(r->calls < 8);
    r->action[r->calls] = action;
    r->reason[r->calls] = reason;
    r->calls++;
    return true;
}

static void start(enum policy_action action, enum policy_watch watch, bool motion_enable,
                  bool single_owner)
{
    struct policy_config cfg = {
        .time_limit_ms = LIMIT,
        .action = action,
        .watch = watch,
        .motion_enable = motion_enable,
        .single_owner = single_owner,
    };
    struct policy_sink sink = {.send_action = record_action, .user = &sent};

    memset(&sent, 0, sizeof(sent));
    policy_init(&p, &cfg, &sink);
}

static void start_heartbeat(enum policy_action action)
{
    start(action, POLICY_WATCH_HEARTBEAT, false, true);
}

/* Checks at every 10 ms from 'from' to 'to' inclusive, as the timer does. */
static void check_span(uint64_t from, uint64_t to, bool moving)
{
    for (uint64_t t = from; t <= to; t += 10)
        policy_check(&p, t, moving);
}

static void expect_nothing(void)
{
    assert_int_equal(sent.calls, 0);
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
    assert_false(policy_blocks_commands(&p));
}

static void expect_one(enum policy_action action, enum policy_fault reason)
{
    assert_int_equal(sent.calls, 1);
    assert_int_equal(sent.action[0], action);
    assert_int_equal(sent.reason[0], reason);
    assert_int_equal(p.fault, reason);
    assert_true(policy_blocks_commands(&p));
}

/* ---- the heartbeat ---- */

static void heartbeat_not_armed_before_a_first_change(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    /* Never written: a PLC that does not use the heartbeat is not judged. */
    check_span(T0, T0 + 5 * LIMIT, MOVING);
    expect_nothing();
    assert_false(p.heartbeat_armed);
}

static void heartbeat_armed_on_first_write(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    /* The first write arms the watch, whatever its value (0 included). */
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 0);
    assert_true(p.heartbeat_armed);
    check_span(T0, T0 + LIMIT - 1, MOVING);
    policy_check(&p, T0 + LIMIT - 1, MOVING);
    expect_nothing();
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
}

static void heartbeat_changes_keep_it_alive(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    for (unsigned i = 0; i < 50; i++) {
        uint64_t t = T0 + i * (LIMIT - 100);
        policy_heartbeat(&p, t, PLC_A, ADDR_A, i);
        check_span(t, t + LIMIT - 110, MOVING);
    }
    expect_nothing();
}

static void same_value_is_not_a_change(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 7);
    /* A PLC stuck writing the same value is silent. */
    for (uint64_t t = T0 + 100; t < T0 + LIMIT; t += 100) {
        policy_heartbeat(&p, t, PLC_A, ADDR_A, 7);
        policy_check(&p, t, MOVING);
    }
    expect_nothing();
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
}

static void loss_while_moving_pauses_once(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 10 * LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(p.faults, 1);
}

static void loss_while_moving_stops_once(void **state)
{
    (void)state;
    start_heartbeat(POLICY_STOP);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 10 * LIMIT, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_HEARTBEAT);
}

static void keep_sends_nothing_but_latches(void **state)
{
    (void)state;
    start_heartbeat(POLICY_KEEP);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 10 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 0);
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(p.faults, 1);
    assert_true(policy_blocks_commands(&p));
}

static void loss_while_idle_does_nothing(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 10 * LIMIT, IDLE);
    expect_nothing();
    assert_int_equal(p.faults, 0);
    assert_int_equal(policy_fault_age_ms(&p, T0 + 10 * LIMIT), 0);
}

static void motion_after_an_idle_loss_acts_once(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 3 * LIMIT, IDLE);
    expect_nothing();
    /* The robot starts moving (a pendant, a program) with the PLC still
     * gone: the first check that sees it acts. */
    policy_check(&p, T0 + 3 * LIMIT + 10, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    check_span(T0 + 3 * LIMIT + 20, T0 + 6 * LIMIT, MOVING);
    check_span(T0 + 6 * LIMIT, T0 + 7 * LIMIT, IDLE);
    check_span(T0 + 7 * LIMIT, T0 + 8 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 1);
}

/* ---- the latch and its reset ---- */

static void latched_fault_never_repeats_and_blocks(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    /* Time passes, the robot keeps moving or stops and starts again: the
     * action went once; the fault stays until the PLC resets it. */
    check_span(T0 + LIMIT, T0 + 20 * LIMIT, MOVING);
    check_span(T0 + 20 * LIMIT, T0 + 21 * LIMIT, IDLE);
    check_span(T0 + 21 * LIMIT, T0 + 22 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 1);
    assert_int_equal(p.faults, 1);
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
    assert_true(policy_blocks_commands(&p));
    /* A heartbeat that resumes does not clear it either. */
    policy_heartbeat(&p, T0 + 22 * LIMIT, PLC_A, ADDR_A, 2);
    check_span(T0 + 22 * LIMIT, T0 + 22 * LIMIT + 500, MOVING);
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
    assert_true(policy_blocks_commands(&p));
}

static void reset_clears_the_fault(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    /* The PLC is back: heartbeat, then reset (the loop turned meanwhile). */
    uint64_t back = T0 + 3 * LIMIT;
    check_span(T0 + LIMIT, back, MOVING);
    policy_heartbeat(&p, back, PLC_A, ADDR_A, 2);
    policy_reset(&p);
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
    assert_false(policy_blocks_commands(&p));
    assert_int_equal(policy_fault_age_ms(&p, back), 0);
    assert_int_equal(p.faults, 1); /* the count of faults ever stays */
    check_span(back, back + LIMIT - 10, MOVING);
    assert_int_equal(sent.calls, 1);
    /* A second loss acts again, once. */
    policy_check(&p, back + LIMIT, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(sent.action[1], POLICY_PAUSE);
    assert_int_equal(p.faults, 2);
    check_span(back + LIMIT, back + 5 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 2);
}

static void reset_without_a_fault_is_harmless(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_reset(&p);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_reset(&p);
    check_span(T0, T0 + LIMIT - 10, MOVING);
    expect_nothing();
    assert_int_equal(p.faults, 0);
}

static void fault_age_counts_from_the_latch(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    assert_int_equal(policy_fault_age_ms(&p, T0), 0);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + LIMIT + 30, IDLE);
    policy_check(&p, T0 + LIMIT + 40, MOVING); /* latches here */
    assert_int_equal(policy_fault_age_ms(&p, T0 + LIMIT + 40), 0);
    assert_int_equal(policy_fault_age_ms(&p, T0 + LIMIT + 290), 250);
    check_span(T0 + LIMIT + 40, T0 + 100 * LIMIT, MOVING);
    assert_int_equal(policy_fault_age_ms(&p, T0 + 100 * LIMIT + 40), 99 * LIMIT);
    policy_reset(&p);
    assert_int_equal(policy_fault_age_ms(&p, T0 + 100 * LIMIT + 40), 0);
}

/* ---- the connection ---- */

static void connection_not_armed_before_a_first_client(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_CONNECTION, false, true);
    check_span(T0, T0 + 5 * LIMIT, MOVING);
    expect_nothing();
}

static void connection_lost_counts_from_the_last_close(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_CONNECTION, false, true);
    policy_client_opened(&p, T0, 1);
    policy_client_opened(&p, T0 + 10, 2);
    /* Connected for long: nothing. */
    check_span(T0, T0 + 5 * LIMIT, MOVING);
    uint64_t t = T0 + 5 * LIMIT;
    policy_client_closed(&p, t, PLC_B, 1);
    check_span(t, t + 3 * LIMIT, MOVING); /* one left: still watched */
    expect_nothing();
    t += 3 * LIMIT;
    policy_client_closed(&p, t, PLC_A, 0);
    check_span(t, t + LIMIT - 10, MOVING);
    policy_check(&p, t + LIMIT - 1, MOVING);
    expect_nothing();
    policy_check(&p, t + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_NO_CLIENT);
    check_span(t + LIMIT, t + 5 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 1);
}

static void client_back_in_time_is_no_fault(void **state)
{
    (void)state;
    start(POLICY_STOP, POLICY_WATCH_CONNECTION, false, true);
    policy_client_opened(&p, T0, 1);
    policy_client_closed(&p, T0 + 100, PLC_A, 0);
    check_span(T0 + 100, T0 + 100 + LIMIT - 10, MOVING);
    policy_client_opened(&p, T0 + LIMIT, 1);
    check_span(T0 + LIMIT, T0 + 5 * LIMIT, MOVING);
    expect_nothing();
    /* It goes again: the limit counts from this close, not the first. */
    uint64_t t = T0 + 5 * LIMIT;
    policy_client_closed(&p, t, PLC_A, 0);
    policy_check(&p, t + LIMIT - 1, MOVING);
    expect_nothing();
    policy_check(&p, t + LIMIT, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_NO_CLIENT);
}

static void connection_lost_while_idle_does_nothing(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_CONNECTION, false, true);
    policy_client_opened(&p, T0, 1);
    policy_client_closed(&p, T0, PLC_A, 0);
    check_span(T0, T0 + 5 * LIMIT, IDLE);
    expect_nothing();
    policy_check(&p, T0 + 5 * LIMIT + 10, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_NO_CLIENT);
}

static void connection_watch_ignores_the_heartbeat(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_CONNECTION, false, true);
    policy_client_opened(&p, T0, 1);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 5 * LIMIT, MOVING);
    expect_nothing();
}

static void heartbeat_watch_ignores_the_connection(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_client_opened(&p, T0, 1);
    policy_client_closed(&p, T0 + 10, PLC_A, 0);
    check_span(T0, T0 + 5 * LIMIT, MOVING);
    expect_nothing();
}

static void both_watches_either_signal(void **state)
{
    (void)state;
    /* The heartbeat stops while a client stays connected. */
    start(POLICY_PAUSE, POLICY_WATCH_BOTH, false, true);
    policy_client_opened(&p, T0, 1);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT - 1, MOVING);
    expect_nothing();
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);

    /* Every client goes while the heartbeat (never written) is unarmed. */
    start(POLICY_STOP, POLICY_WATCH_BOTH, false, true);
    policy_client_opened(&p, T0, 1);
    policy_client_closed(&p, T0 + 10, PLC_A, 0);
    policy_check(&p, T0 + 10 + LIMIT - 1, MOVING);
    expect_nothing();
    policy_check(&p, T0 + 10 + LIMIT, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_NO_CLIENT);

    /* Both lost at once: one action, one fault. */
    start(POLICY_PAUSE, POLICY_WATCH_BOTH, false, true);
    policy_client_opened(&p, T0, 1);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_client_closed(&p, T0 + 10, PLC_A, 0);
    check_span(T0, T0 + 5 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 1);
    assert_int_equal(p.faults, 1);
    assert_int_not_equal(p.fault, POLICY_FAULT_NONE);
}

/* ---- the motion-enable coil ---- */

static void motion_enable_drop_pauses_at_once(void **state)
{
    (void)state;
    start(POLICY_STOP, POLICY_WATCH_HEARTBEAT, true, true);
    /* Required and not yet given: commands are refused, nothing latched. */
    assert_true(policy_blocks_commands(&p));
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
    policy_motion_enable(&p, T0, true, IDLE);
    assert_false(policy_blocks_commands(&p));
    /* Held again: no change. */
    policy_motion_enable(&p, T0 + 10, true, MOVING);
    assert_int_equal(sent.calls, 0);
    /* Dropped while the program runs: pause_program now, no check needed. */
    policy_motion_enable(&p, T0 + 20, false, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE);
    assert_int_equal(policy_fault_age_ms(&p, T0 + 20), 0);
    check_span(T0 + 20, T0 + 5 * LIMIT, MOVING);
    /* Raised and dropped again while it moves: an explicit request to
     * pause, like releasing a hold-to-run switch, sent each time; the
     * latched fault stays the first one. */
    policy_motion_enable(&p, T0 + 5 * LIMIT, true, MOVING);
    policy_motion_enable(&p, T0 + 5 * LIMIT + 10, false, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(sent.action[1], POLICY_PAUSE);
    assert_int_equal(p.faults, 1);
    /* Reset with the coil back at 1: commands pass again. */
    policy_motion_enable(&p, T0 + 6 * LIMIT, true, IDLE);
    policy_reset(&p);
    assert_false(policy_blocks_commands(&p));
}

static void motion_enable_drop_while_idle_latches_nothing(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, true);
    policy_motion_enable(&p, T0, true, IDLE);
    /* policy.h: "A loss while the robot is idle sends nothing and latches
     * nothing." Commands stay refused while the coil is 0 (that is the
     * coil's purpose), and raising it again lets them pass without a
     * reset. */
    policy_motion_enable(&p, T0 + 10, false, IDLE);
    assert_int_equal(sent.calls, 0);
    assert_true(policy_blocks_commands(&p));
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
    assert_int_equal(p.faults, 0);
    policy_motion_enable(&p, T0 + 20, true, IDLE);
    assert_false(policy_blocks_commands(&p));
}

static void motion_enable_not_required(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, false, true);
    assert_false(policy_blocks_commands(&p));
    policy_motion_enable(&p, T0, true, MOVING);
    policy_motion_enable(&p, T0 + 10, false, MOVING);
    expect_nothing();
    assert_false(p.motion_enabled); /* still shown as written */
}

static void motion_enable_drop_under_a_latched_fault(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, true);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    /* The coil dropped while it still moves (action keep, or a pause the
     * robot did not carry out): pause now; the heartbeat fault stays. */
    policy_motion_enable(&p, T0 + LIMIT + 10, false, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(sent.action[1], POLICY_PAUSE);
    /* Its own reason, not the latched heartbeat's (the log says why). */
    assert_int_equal(sent.reason[1], POLICY_FAULT_MOTION_ENABLE);
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(p.faults, 1);
    /* Idle, a drop sends nothing. */
    policy_motion_enable(&p, T0 + LIMIT + 20, true, IDLE);
    policy_motion_enable(&p, T0 + LIMIT + 30, false, IDLE);
    assert_int_equal(sent.calls, 2);
}

/*
 * issue 23: a start the gateway sent counts as running until a status
 * document received after its reply: motion enable dropped in between
 * pauses, though the status still reads idle. Before, the drop was judged
 * on the status alone and sent nothing.
 */
static void drop_after_a_start_not_shown_yet_pauses(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, false);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_start_sent(&p, T0 + 1);
    policy_motion_enable(&p, T0 + 2, false, IDLE); /* queued, unanswered */
    expect_one(POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE);

    /* Answered: until a document received after the reply, still running. */
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, false);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_start_sent(&p, T0 + 1);
    policy_start_answered(&p, T0 + 5);
    policy_status_document(&p, T0 + 5); /* the same millisecond: may predate it */
    assert_true(policy_start_unshown(&p, T0 + 5));
    /* Too soon after the reply: the controller's status may lag it. */
    policy_status_document(&p, T0 + 5 + POLICY_START_SETTLE_MS - 1);
    assert_true(policy_start_unshown(&p, T0 + 5 + POLICY_START_SETTLE_MS - 1));
    policy_motion_enable(&p, T0 + 6, false, IDLE);
    expect_one(POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE);

    /* A document after the reply reading idle: the start did not run. */
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, false);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_start_sent(&p, T0 + 1);
    policy_start_answered(&p, T0 + 5);
    policy_status_document(&p, T0 + 5 + POLICY_START_SETTLE_MS);
    assert_false(policy_start_unshown(&p, T0 + 5 + POLICY_START_SETTLE_MS));
    policy_motion_enable(&p, T0 + 6 + POLICY_START_SETTLE_MS, false, IDLE);
    assert_int_equal(sent.calls, 0);
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
}

/* Two starts: documents count only once both are answered; answered, the
 * mark lasts start_unshown_max_ms at most without a document. */
static void starts_unshown_until_the_last_reply_or_the_bound(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, false);
    p.cfg.start_unshown_max_ms = 500;
    policy_start_sent(&p, T0);
    policy_start_sent(&p, T0 + 10);
    policy_start_answered(&p, T0 + 20);
    policy_status_document(&p, T0 + 30);
    assert_true(policy_start_unshown(&p, T0 + 30)); /* one still unanswered */
    policy_start_answered(&p, T0 + 40);
    policy_status_document(&p, T0 + 40);
    assert_true(policy_start_unshown(&p, T0 + 40));
    policy_status_document(&p, T0 + 40 + POLICY_START_SETTLE_MS);
    assert_false(policy_start_unshown(&p, T0 + 40 + POLICY_START_SETTLE_MS));
    /* Unanswered, it may start any moment, however long it waits. */
    policy_start_sent(&p, T0 + 100);
    assert_true(policy_start_unshown(&p, T0 + 100 + 10 * LIMIT));
    /* Answered, no document: counted as running up to the bound. */
    policy_start_answered(&p, T0 + 200);
    assert_true(policy_start_unshown(&p, T0 + 200 + 499));
    assert_false(policy_start_unshown(&p, T0 + 200 + 500));
    /* Unset: 10 s. */
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, false);
    policy_start_sent(&p, T0);
    policy_start_answered(&p, T0);
    assert_true(policy_start_unshown(&p, T0 + 9999));
    assert_false(policy_start_unshown(&p, T0 + 10000));
}

/* Motion enable is a level, judged every period like the heartbeat: at 0
 * (armed) while idle nothing; the program started from elsewhere is
 * paused at the next check, once. */
static void motion_enable_at_0_pauses_a_later_start(void **state)
{
    (void)state;
    start(POLICY_STOP, POLICY_WATCH_HEARTBEAT, true, false);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_motion_enable(&p, T0 + 10, false, IDLE);
    check_span(T0 + 10, T0 + 5 * LIMIT, IDLE);
    assert_int_equal(sent.calls, 0);
    policy_check(&p, T0 + 5 * LIMIT + 10, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE); /* pause, not the configured stop */
    check_span(T0 + 5 * LIMIT + 20, T0 + 10 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 1);
    /* Reset while it still runs with the coil at 0: latched again at once. */
    policy_reset(&p);
    policy_check(&p, T0 + 10 * LIMIT + 10, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(p.fault, POLICY_FAULT_MOTION_ENABLE);
    /* Never armed: a 0 from the start judges nothing. */
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, false);
    policy_motion_enable(&p, T0, false, MOVING);
    check_span(T0, T0 + LIMIT, MOVING);
    assert_int_equal(sent.calls, 0);
    assert_true(policy_blocks_commands(&p));
}

/* The command path consults the same rule: a start while a signal is lost
 * is refused and latches that fault with its action, as if it had gone
 * out; what starts nothing passes. */
static void gate_start_while_a_signal_is_lost(void **state)
{
    (void)state;
    char why[96];
    const struct cmd_def *play = cmd_find("play_program");
    const struct cmd_def *power_on = cmd_find("power_on");

    start(POLICY_STOP, POLICY_WATCH_HEARTBEAT, true, false);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_motion_enable(&p, T0 + 10, false, IDLE);
    assert_int_equal(policy_gate_command(&p, T0 + 20, power_on, why, sizeof(why)), 0);
    assert_int_equal(policy_gate_command(&p, T0 + 20, play, why, sizeof(why)), 1);
    assert_string_equal(why, "motion enable dropped: fault 3 latched");
    assert_true(strlen(why) <= 40); /* whole in a result's 20 registers */
    expect_one(POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE);

    /* The heartbeat lost, the robot idle: a start latches fault 1 and the
     * configured action (stop). */
    start(POLICY_STOP, POLICY_WATCH_HEARTBEAT, false, false);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 2 * LIMIT, IDLE);
    assert_int_equal(sent.calls, 0);
    assert_int_equal(policy_gate_command(&p, T0 + 2 * LIMIT, power_on, why, sizeof(why)), 0);
    assert_int_equal(policy_gate_command(&p, T0 + 2 * LIMIT, NULL, why, sizeof(why)), 1);
    assert_string_equal(why, "PLC heartbeat lost: fault 1 latched");
    assert_true(strlen(why) <= 40); /* whole in a result's 20 registers */
    expect_one(POLICY_STOP, POLICY_FAULT_HEARTBEAT);
}

/* Several signals lost at once: the first (heartbeat, connection, motion
 * enable) is the fault; the strongest action goes out, once. */
static void several_lost_at_once(void **state)
{
    (void)state;
    start(POLICY_KEEP, POLICY_WATCH_HEARTBEAT, true, false);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_motion_enable(&p, T0 + 10, false, IDLE);
    check_span(T0 + 10, T0 + LIMIT + 10, IDLE);
    assert_int_equal(sent.calls, 0);
    policy_check(&p, T0 + LIMIT + 20, MOVING);
    assert_int_equal(sent.calls, 1);
    assert_int_equal(sent.action[0], POLICY_PAUSE); /* keep for the heartbeat, pause for motion enable */
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
    check_span(T0 + LIMIT + 30, T0 + 3 * LIMIT, MOVING);
    assert_int_equal(sent.calls, 1);
}

/* An action that cannot go out (the command link is down) stays owed and
 * goes out at the first check at which it can, while the robot may move. */
static bool refuse_then_accept(void *user, enum policy_action action, enum policy_fault reason)
{
    struct sink_record *r = user;
    r->action[r->calls] = action;
    r->reason[r->calls] = reason;
    r->calls++;
    return r->calls >= 3;
}

static void an_action_that_cannot_go_out_stays_owed(void **state)
{
    (void)state;
    start(POLICY_STOP, POLICY_WATCH_HEARTBEAT, false, true);
    p.sink.send_action = refuse_then_accept;
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    assert_int_equal(sent.calls, 1); /* tried, refused */
    assert_int_equal(p.owed, POLICY_STOP);
    policy_check(&p, T0 + LIMIT + 10, IDLE);
    assert_int_equal(sent.calls, 1); /* idle: nothing to stop */
    policy_check(&p, T0 + LIMIT + 20, MOVING);
    assert_int_equal(sent.calls, 2);
    policy_check(&p, T0 + LIMIT + 30, MOVING);
    assert_int_equal(sent.calls, 3); /* sent at last */
    assert_int_equal(p.owed, POLICY_KEEP);
    policy_check(&p, T0 + LIMIT + 40, MOVING);
    assert_int_equal(sent.calls, 3); /* and never again while latched */
    assert_int_equal(sent.action[2], POLICY_STOP);
    assert_int_equal(p.faults, 1);
}

/*
 * The action went out, then its connection was lost before its reply: the
 * robot may never have had it. Owed again, it goes out at the next check
 * while the robot runs or may run, once; a loss with no fault latched (the
 * PLC reset it) owes nothing.
 */
static void an_action_with_outcome_unknown_is_owed_again(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    policy_action_unknown(&p, POLICY_PAUSE);
    assert_int_equal(p.owed, POLICY_PAUSE);
    policy_check(&p, T0 + LIMIT + 10, IDLE);
    assert_int_equal(sent.calls, 1); /* shown paused: nothing to send */
    policy_check(&p, T0 + LIMIT + 20, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(sent.action[1], POLICY_PAUSE);
    assert_int_equal(sent.reason[1], POLICY_FAULT_HEARTBEAT);
    check_span(T0 + LIMIT + 30, T0 + LIMIT + 500, MOVING);
    assert_int_equal(sent.calls, 2); /* once */
    assert_int_equal(p.faults, 1);
    policy_reset(&p);
    policy_action_unknown(&p, POLICY_PAUSE);
    assert_int_equal(p.owed, POLICY_KEEP);
}

/* ---- the write owner ---- */

static void owner_is_the_heartbeat_writer(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    /* Nobody owns it before a heartbeat: anyone may write. */
    assert_int_equal(policy_may_write(&p, PLC_A), 0);
    assert_int_equal(policy_may_write(&p, PLC_B), 0);
    assert_string_equal(p.owner_address, "");
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    assert_int_equal(p.owner, PLC_A);
    assert_string_equal(p.owner_address, ADDR_A);
    assert_int_equal(policy_may_write(&p, PLC_A), 0);
    assert_int_equal(policy_may_write(&p, PLC_B), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    /* Kept while the heartbeat lives. */
    for (unsigned i = 1; i < 10; i++) {
        policy_heartbeat(&p, T0 + i * 500, PLC_A, ADDR_A, 1 + i);
        check_span(T0 + i * 500, T0 + i * 500 + 490, IDLE);
        assert_int_equal(policy_may_write(&p, PLC_B), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    }
}

static void owner_released_when_it_disconnects(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_client_opened(&p, T0, 1);
    policy_client_opened(&p, T0, 2);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    /* Another client's close changes nothing. */
    policy_client_closed(&p, T0 + 10, PLC_B, 1);
    assert_int_equal(policy_may_write(&p, PLC_B), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    policy_client_closed(&p, T0 + 20, PLC_A, 0);
    assert_int_equal(p.owner, 0);
    assert_string_equal(p.owner_address, "");
    assert_int_equal(policy_may_write(&p, PLC_B), 0);
    /* The next heartbeat writer takes it. */
    policy_heartbeat(&p, T0 + 30, PLC_B, ADDR_B, 2);
    assert_int_equal(p.owner, PLC_B);
    assert_string_equal(p.owner_address, ADDR_B);
    assert_int_equal(policy_may_write(&p, PLC_A), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
}

static void owner_released_when_its_heartbeat_expires(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT - 1, IDLE);
    assert_int_equal(p.owner, PLC_A);
    policy_check(&p, T0 + LIMIT, IDLE);
    assert_int_equal(p.owner, 0);
    assert_string_equal(p.owner_address, "");
    assert_int_equal(policy_may_write(&p, PLC_B), 0);
    expect_nothing(); /* idle: released, nothing latched */
    policy_heartbeat(&p, T0 + LIMIT + 10, PLC_B, ADDR_B, 50);
    assert_int_equal(p.owner, PLC_B);
    assert_int_equal(policy_may_write(&p, PLC_A), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    /* B's heartbeat lives on: B keeps it. */
    policy_heartbeat(&p, T0 + LIMIT + 500, PLC_B, ADDR_B, 51);
    check_span(T0 + LIMIT + 500, T0 + 2 * LIMIT + 400, MOVING);
    assert_int_equal(p.owner, PLC_B);
    expect_nothing();
}

static void owner_released_on_expiry_while_latched(void **state)
{
    (void)state;
    start_heartbeat(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    /* A standby PLC can take over, feed the heartbeat and reset. */
    assert_int_equal(p.owner, 0);
    assert_int_equal(policy_may_write(&p, PLC_B), 0);
    policy_heartbeat(&p, T0 + LIMIT + 100, PLC_B, ADDR_B, 9);
    assert_int_equal(p.owner, PLC_B);
    policy_reset(&p);
    check_span(T0 + LIMIT + 100, T0 + 2 * LIMIT + 90, MOVING);
    assert_int_equal(sent.calls, 1);
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
    assert_int_equal(p.owner, PLC_B);
}

static void no_owner_without_single_owner(void **state)
{
    (void)state;
    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, false, false);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    assert_int_equal(p.owner, 0);
    assert_string_equal(p.owner_address, "");
    assert_int_equal(policy_may_write(&p, PLC_B), 0);
    /* B's heartbeat counts as well. */
    check_span(T0, T0 + 890, MOVING);
    policy_heartbeat(&p, T0 + 900, PLC_B, ADDR_B, 2);
    check_span(T0 + 900, T0 + 900 + LIMIT - 10, MOVING);
    expect_nothing();
}

/* ---- the decisions gateway.c used to take ---- */

static void set_num(struct jaka_status *st, enum status_field f, double v)
{
    struct status_num *n = (struct status_num *)status_num_at(st, f, 0);
    n->value = v;
    n->present = true;
}

static void robot_may_move_assumes_the_worst_when_blind(void **state)
{
    (void)state;
    static struct jaka_status st;

    memset(&st, 0, sizeof(st));
    /* Stale or absent status: it may move. */
    assert_true(policy_robot_may_move(false, &st));
    assert_true(policy_robot_may_move(true, NULL));
    /* Fresh, idle and in position: it does not. */
    set_num(&st, STATUS_F_interp_state, 0);
    set_num(&st, STATUS_F_inpos, 1);
    assert_false(policy_robot_may_move(true, &st));
    /* A program loading or running, or not in position: it may. */
    set_num(&st, STATUS_F_interp_state, 1);
    assert_true(policy_robot_may_move(true, &st));
    set_num(&st, STATUS_F_interp_state, 3);
    assert_true(policy_robot_may_move(true, &st));
    set_num(&st, STATUS_F_interp_state, 2); /* paused */
    assert_false(policy_robot_may_move(true, &st));
    set_num(&st, STATUS_F_inpos, 0);
    assert_true(policy_robot_may_move(true, &st));
}

static void gate_refuses_under_a_fault_and_without_motion_enable(void **state)
{
    (void)state;
    char why[96];
    const struct cmd_def *power_on = cmd_find("power_on");
    const struct cmd_def *play = cmd_find("play_program");
    const struct cmd_def *joint_move = cmd_find("joint_move");
    const struct cmd_def *stop = cmd_find("stop_program");

    start(POLICY_PAUSE, POLICY_WATCH_HEARTBEAT, true, false);
    /* Motion enable required and at 0: motion, program starts and unknown
     * names (judged as motion) are refused; the rest passes. */
    assert_int_equal(policy_gate_command(&p, T0, power_on, why, sizeof(why)), 0);
    assert_int_equal(policy_gate_command(&p, T0, play, why, sizeof(why)), 1);
    assert_string_equal(why, "motion enable is 0");
    assert_true(strlen(why) <= 40); /* whole in a result's 20 registers */
    assert_int_equal(policy_gate_command(&p, T0, joint_move, why, sizeof(why)), 1);
    assert_int_equal(policy_gate_command(&p, T0, NULL, why, sizeof(why)), 1);
    policy_motion_enable(&p, T0, true, IDLE);
    assert_int_equal(policy_gate_command(&p, T0, play, why, sizeof(why)), 0);
    assert_int_equal(policy_gate_command(&p, T0, NULL, why, sizeof(why)), 0);
    /* A latched fault refuses everything but stop_program. */
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    assert_int_equal(policy_gate_command(&p, T0 + LIMIT, power_on, why, sizeof(why)), 1);
    assert_string_equal(why, "fault 1 latched: reset it first");
    assert_true(strlen(why) <= 40); /* whole in a result's 20 registers */
    assert_int_equal(policy_gate_command(&p, T0 + LIMIT, NULL, why, sizeof(why)), 1);
    assert_int_equal(policy_gate_command(&p, T0 + LIMIT, stop, why, sizeof(why)), 0);
}

static void sink_without_a_callback(void **state)
{
    (void)state;
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = POLICY_PAUSE,
                                .watch = POLICY_WATCH_HEARTBEAT};
    struct policy_sink none = {0};
    policy_init(&p, &cfg, &none);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, MOVING);
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
}


/* The stalls the sink was told of (sink.on_stall). */
static uint64_t stall_gaps[4];
static unsigned stall_calls;

static void record_stall(void *user, uint64_t gap_ms)
{
    (void)user;
    assert_true(stall_calls < 4);
    stall_gaps[stall_calls++] = gap_ms;
}

static void start_with_stall_sink(enum policy_action action)
{
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = action,
                                .watch = POLICY_WATCH_BOTH, .single_owner = true};
    struct policy_sink sink = {.send_action = record_action, .on_stall = record_stall,
                               .user = &sent};

    memset(&sent, 0, sizeof(sent));
    stall_calls = 0;
    policy_init(&p, &cfg, &sink);
}

/*
 * The gateway's process stopped for 70 s with a program running (the
 * review's SIGSTOP): when the loop turns again, the fault is the
 * gateway's own (4), never "PLC heartbeat lost"; the configured action
 * still goes out once; the stall is reported once, with its length.
 */
static void stall_is_the_gateways_fault_not_the_plcs(void **state)
{
    (void)state;
    start_with_stall_sink(POLICY_STOP);
    policy_client_opened(&p, T0, 1);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 500, MOVING);
    expect_nothing();
    /* Stopped at T0 + 500, resumed 70 s later: the first check. */
    uint64_t resumed = T0 + 500 + 70000;
    policy_check(&p, resumed, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_GATEWAY_STALL);
    assert_string_equal(policy_fault_name(p.fault), "gateway loop stalled");
    assert_int_equal(stall_calls, 1);
    assert_int_equal(stall_gaps[0], 70000);
    assert_int_equal(p.stalls, 1);
    assert_int_equal(p.last_stall_ms, 70000);
    /* The PLC's heartbeat was 500 ms old when the gateway stopped: it
     * still is, and the PLC has its whole limit to be heard again. */
    check_span(resumed, resumed + LIMIT - 510, MOVING);
    for (uint64_t t = resumed + LIMIT - 500; t <= resumed + 3 * LIMIT; t += 500) {
        policy_heartbeat(&p, t, PLC_A, ADDR_A, (double)t);
        check_span(t, t + 490, MOVING);
    }
    assert_int_equal(sent.calls, 1);
    assert_int_equal(p.fault, POLICY_FAULT_GATEWAY_STALL);
    assert_int_equal(stall_calls, 1);
    /* Commands are refused until the PLC resets it, stop excepted. */
    assert_true(policy_blocks_commands(&p));
    policy_reset(&p);
    policy_check(&p, resumed + 3 * LIMIT + 490, MOVING);
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
    assert_int_equal(sent.calls, 1);
}

/* A stall while the robot is idle is reported, and latches nothing; one
 * just within the limit is no stall at all. */
static void stall_while_idle_only_reported(void **state)
{
    (void)state;
    start_with_stall_sink(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    policy_check(&p, T0 + LIMIT, IDLE); /* a gap of exactly the limit */
    assert_int_equal(stall_calls, 0);
    policy_heartbeat(&p, T0 + LIMIT, PLC_A, ADDR_A, 2);
    policy_check(&p, T0 + 5 * LIMIT, IDLE);
    assert_int_equal(stall_calls, 1);
    assert_int_equal(stall_gaps[0], 4 * LIMIT);
    expect_nothing();
    /* Judged once: the robot moving afterwards is not a second stall. */
    check_span(T0 + 5 * LIMIT, T0 + 5 * LIMIT + 500, MOVING);
    expect_nothing();
}

/* A stall seen first by a write (the loop's I/O runs before its timers)
 * shifts the PLC's clock before the write is judged: the heartbeat write
 * waiting in the socket is not late, and a start waiting behind it is
 * refused for the gateway's stall, not for the PLC's heartbeat. */
static void stall_seen_by_a_write_first(void **state)
{
    (void)state;
    start_with_stall_sink(POLICY_PAUSE);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 300, IDLE);
    uint64_t resumed = T0 + 300 + 20000;
    char why[96] = "";
    int ex = policy_gate_command(&p, resumed, NULL, why, sizeof(why));
    assert_int_equal(ex, MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    expect_one(POLICY_PAUSE, POLICY_FAULT_GATEWAY_STALL);
    assert_non_null(strstr(why, "fault 4"));
    assert_int_equal(stall_calls, 1);
}

/*
 * A turn late by less than the limit (the review's SIGSTOP of 0.9 s with
 * a PLC beating every 200 ms): libuv runs its timers before it polls, so
 * the first check after it comes before the heartbeat waiting in the
 * socket is read. It used to latch "PLC heartbeat lost" (fault 1) and
 * pause a running program; the heartbeat's verdict now waits for that
 * turn's input. A PLC really gone is still caught one check later:
 * within the limit, the late turn and one check period.
 */
static void late_turn_waits_for_its_input(void **state)
{
    (void)state;
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = POLICY_PAUSE,
                                .watch = POLICY_WATCH_BOTH, .check_period_ms = 100};
    struct policy_sink sink = {.send_action = record_action, .user = &sent};

    memset(&sent, 0, sizeof(sent));
    policy_init(&p, &cfg, &sink);
    policy_client_opened(&p, T0, 1);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 100, MOVING);
    /* Stopped at T0 + 100, resumed at T0 + 1000: the timers first. */
    policy_check(&p, T0 + 1000, MOVING);
    expect_nothing();
    /* Then the poll: the heartbeat written meanwhile. */
    policy_heartbeat(&p, T0 + 1000, PLC_A, ADDR_A, 2);
    check_span(T0 + 1010, T0 + 1900, MOVING);
    expect_nothing();
    /* The same late turn with the PLC gone: caught at the next check. */
    policy_check(&p, T0 + 1900 + 900, MOVING);
    expect_nothing();
    policy_check(&p, T0 + 1900 + 1000, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
}

/* A loop late on every turn (250 ms, the check period 100) still judges
 * a PLC gone, one turn after its limit: never a deferral after another. */
static void loop_late_on_every_turn_still_judges(void **state)
{
    (void)state;
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = POLICY_PAUSE,
                                .watch = POLICY_WATCH_BOTH, .check_period_ms = 100};
    struct policy_sink sink = {.send_action = record_action, .user = &sent};

    memset(&sent, 0, sizeof(sent));
    policy_init(&p, &cfg, &sink);
    policy_client_opened(&p, T0, 1);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    uint64_t t = T0;
    while (sent.calls == 0 && t < T0 + 10 * LIMIT) {
        t += 250;
        policy_check(&p, t, MOVING);
    }
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    assert_true(t <= T0 + LIMIT + 250);
}

/*
 * A stall of 1.5 s with the robot idle: at the first check after it the
 * status looks stale (its documents are still in the socket), so the
 * gateway passes "may move"; fault 4 latched and a pause went out for an
 * idle robot (the review's SIGSTOP, jakasim idle: fault 4 every time). The
 * stall is now judged by the next check, with the status read: idle, it
 * is only reported. Running, it latches at the next tick of the check
 * period, after a poll.
 */
static void stall_judged_with_the_status_read_after_it(void **state)
{
    (void)state;
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = POLICY_PAUSE,
                                .watch = POLICY_WATCH_BOTH, .check_period_ms = 100};
    struct policy_sink sink = {.send_action = record_action, .on_stall = record_stall,
                               .user = &sent};

    memset(&sent, 0, sizeof(sent));
    stall_calls = 0;
    policy_init(&p, &cfg, &sink);
    policy_client_opened(&p, T0, 1);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    check_span(T0, T0 + 100, IDLE);
    policy_check(&p, T0 + 1600, MOVING); /* blind: the status is stale */
    assert_int_equal(stall_calls, 1);
    expect_nothing();
    policy_heartbeat(&p, T0 + 1600, PLC_A, ADDR_A, 2);
    check_span(T0 + 1700, T0 + 2500, IDLE); /* the status read: idle */
    expect_nothing();
    assert_int_equal(p.stalls, 1);
    policy_heartbeat(&p, T0 + 2500, PLC_A, ADDR_A, 3);
    check_span(T0 + 2510, T0 + 2600, MOVING); /* judged once: no fault now */
    expect_nothing();
    /* The same stall with a program running: fault 4, one check later. */
    policy_heartbeat(&p, T0 + 2600, PLC_A, ADDR_A, 4);
    policy_check(&p, T0 + 4100, MOVING);
    policy_check(&p, T0 + 4110, MOVING); /* a write read in that poll */
    expect_nothing();
    policy_check(&p, T0 + 4200, MOVING); /* the next tick */
    expect_one(POLICY_PAUSE, POLICY_FAULT_GATEWAY_STALL);
}


/* ---- the PLC contract: the owner is a PLC, no motion without a heartbeat ---- */

#define ADDR_A2 "192.0.2.10:50009" /* PLC A's second connection */
#define PLC_A2 3

static void start_owner(bool by_connection, bool require_heartbeat)
{
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = POLICY_PAUSE,
                                .watch = POLICY_WATCH_HEARTBEAT, .single_owner = true,
                                .owner_by_connection = by_connection,
                                .require_heartbeat = require_heartbeat};
    struct policy_sink sink = {.send_action = record_action, .user = &sent};

    memset(&sent, 0, sizeof(sent));
    policy_init(&p, &cfg, &sink);
}

static void owner_host_lets_every_connection_of_the_plc_write(void **state)
{
    (void)state;
    start_owner(false, false);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    /* Its address and port, as IR 66 shows it. */
    assert_string_equal(p.owner_address, ADDR_A);
    /* The same PLC's other connection (reads on one, writes on another). */
    assert_int_equal(policy_may_write_from(&p, PLC_A2, ADDR_A2), 0);
    assert_int_equal(policy_may_write_from(&p, PLC_B, ADDR_B), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    /* An address that only starts like the owner's is another host. */
    assert_int_equal(policy_may_write_from(&p, PLC_B, "192.0.2.100:50001"),
                     MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    /* Only the owner's connection feeds the heartbeat: another program
     * on the PLC's host cannot keep it alive while the PLC is halted. */
    assert_int_equal(policy_may_feed_heartbeat(&p, PLC_A), 0);
    assert_int_equal(policy_may_feed_heartbeat(&p, PLC_A2), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    /* A TLS owner: a plain connection from its address never shares its
     * rights; a TLS one does. */
    policy_owner_transport(&p, PLC_A, "mbaps");
    assert_int_equal(policy_may_write_via(&p, PLC_A2, ADDR_A2, "modbus"),
                     MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    assert_int_equal(policy_may_write_via(&p, PLC_A2, ADDR_A2, "mbaps"), 0);
    /* IPv6, colons and all. */
    start_owner(false, false);
    policy_heartbeat(&p, T0, PLC_A, "2001:db8::7:40122", 1);
    assert_int_equal(policy_may_write_from(&p, PLC_A2, "2001:db8::7:40200"), 0);
    assert_int_equal(policy_may_write_from(&p, PLC_B, "2001:db8::8:40122"),
                     MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    /* owner = connection: only the heartbeat's own connection. */
    start_owner(true, false);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
    assert_int_equal(policy_may_write_from(&p, PLC_A, ADDR_A), 0);
    assert_int_equal(policy_may_write_from(&p, PLC_A2, ADDR_A2),
                     MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
}

static void no_start_before_the_heartbeat_changed(void **state)
{
    (void)state;
    char why[96];
    const struct cmd_def *play = cmd_find("play_program");
    const struct cmd_def *resume = cmd_find("resume_program");
    const struct cmd_def *joint_move = cmd_find("joint_move");
    const char *free_to_go[] = {"power_on", "enable_robot", "set_digital_output", "rapid_rate",
                                "stop_program", "pause_program", "load_program"};

    start_owner(false, true);
    assert_int_equal(policy_heartbeat_state(&p, T0), POLICY_HEARTBEAT_NEVER);
    assert_int_equal(policy_gate_command(&p, T0, play, why, sizeof(why)), 1);
    assert_string_equal(why, "heartbeat not started");
    assert_true(strlen(why) <= 40); /* whole in a result's 20 registers */
    assert_int_equal(policy_gate_command(&p, T0, resume, why, sizeof(why)), 1);
    assert_int_equal(policy_gate_command(&p, T0, joint_move, why, sizeof(why)), 1);
    assert_int_equal(policy_gate_command(&p, T0, NULL, why, sizeof(why)), 1);
    for (unsigned i = 0; i < sizeof(free_to_go) / sizeof(free_to_go[0]); i++)
        assert_int_equal(policy_gate_command(&p, T0, cmd_find(free_to_go[i]), why, sizeof(why)),
                         0);
    assert_int_equal(sent.calls, 0); /* a refusal, no fault */
    assert_int_equal(p.fault, POLICY_FAULT_NONE);
    /* The same value (0, as the register reads at start) is no change. */
    policy_heartbeat(&p, T0 + 10, PLC_A, ADDR_A, 0);
    assert_int_equal(policy_heartbeat_state(&p, T0 + 10), POLICY_HEARTBEAT_NEVER);
    assert_int_equal(policy_gate_command(&p, T0 + 10, play, why, sizeof(why)), 1);
    policy_heartbeat(&p, T0 + 20, PLC_A, ADDR_A, 1);
    assert_int_equal(policy_heartbeat_state(&p, T0 + 20), POLICY_HEARTBEAT_RUNNING);
    assert_int_equal(policy_gate_command(&p, T0 + 20, play, why, sizeof(why)), 0);
    /* Lost: the state says so (and the loss rule takes over). */
    assert_int_equal(policy_heartbeat_state(&p, T0 + 20 + LIMIT - 1), POLICY_HEARTBEAT_RUNNING);
    assert_int_equal(policy_heartbeat_state(&p, T0 + 20 + LIMIT), POLICY_HEARTBEAT_LOST);
    policy_heartbeat(&p, T0 + 30 + LIMIT, PLC_A, ADDR_A, 2);
    assert_int_equal(policy_heartbeat_state(&p, T0 + 30 + LIMIT), POLICY_HEARTBEAT_RUNNING);
    /* require_heartbeat = false: a start goes without one. */
    start_owner(false, false);
    assert_int_equal(policy_gate_command(&p, T0, play, why, sizeof(why)), 0);
}

/* ---- what the action is, and whether the robot did it ---- */

static enum policy_robot robot_now;
static enum policy_reaction reactions[16];
static unsigned reaction_calls;

static enum policy_robot fake_robot(void *user)
{
    (void)user;
    return robot_now;
}

static void record_reaction(void *user, enum policy_reaction reaction, enum policy_action sent_,
                            uint64_t after_ms)
{
    (void)user, (void)sent_, (void)after_ms;
    if (reaction_calls < 16)
        reactions[reaction_calls] = reaction;
    reaction_calls++;
}

#define PERIOD 20 /* the status period of these tests */
#define CHECK 10  /* their check period */

static void start_with_robot(enum policy_action action, bool motion_enable,
                             enum policy_robot robot)
{
    struct policy_config cfg = {.time_limit_ms = LIMIT, .action = action,
                                .watch = POLICY_WATCH_HEARTBEAT,
                                .motion_enable = motion_enable, .check_period_ms = CHECK};
    struct policy_sink sink = {.send_action = record_action, .robot = fake_robot,
                               .on_reaction = record_reaction, .user = &sent};

    memset(&sent, 0, sizeof(sent));
    reaction_calls = 0;
    robot_now = robot;
    policy_init(&p, &cfg, &sink);
    /* Documents every PERIOD ms up to T0: the period is known. */
    for (uint64_t t = T0 - 10 * PERIOD; t <= T0; t += PERIOD)
        policy_status_document(&p, t);
    policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
}

/* Time passes from 'from' to 'to': a document every PERIOD ms, a check
 * every CHECK ms, the robot as robot_now says. */
static void run_span(uint64_t from, uint64_t to, bool moving)
{
    for (uint64_t t = from; t <= to; t += CHECK) {
        if ((t - T0) % PERIOD == 0)
            policy_status_document(&p, t);
        policy_check(&p, t, moving);
    }
}

static void heartbeat_lost_at(uint64_t t, bool moving)
{
    run_span(T0, t, moving);
}

static void pause_becomes_stop_for_a_move_outside_a_program(void **state)
{
    (void)state;
    /* The issue: pause_program answered "no program is running" and the
     * move went on. Moving with no program: stop_program. */
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_MOVING);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(p.reaction, POLICY_REACTION_SENT);
    /* Motion enable's own action likewise. */
    start_with_robot(POLICY_PAUSE, true, POLICY_ROBOT_MOVING);
    policy_motion_enable(&p, T0, true, MOVING);
    policy_motion_enable(&p, T0 + 5, false, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_MOTION_ENABLE);
}

static void pause_stays_pause_for_a_program(void **state)
{
    (void)state;
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_PROGRAM);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    start_with_robot(POLICY_PAUSE, true, POLICY_ROBOT_PROGRAM);
    policy_motion_enable(&p, T0, true, MOVING);
    policy_motion_enable(&p, T0 + 5, false, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE);
    /* stop configured: stop, whatever runs. */
    start_with_robot(POLICY_STOP, false, POLICY_ROBOT_PROGRAM);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_HEARTBEAT);
}

static void move_not_shown_yet_is_stopped(void **state)
{
    (void)state;
    /* A joint_move answered, the status still shows the arm in position
     * where it was (the controller's lag): the drop stops it. */
    start_with_robot(POLICY_PAUSE, true, POLICY_ROBOT_STILL);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_start_sent(&p, T0 + 1);
    policy_start_kind(&p, true);
    policy_start_answered(&p, T0 + 3);
    policy_motion_enable(&p, T0 + 30, false, IDLE);
    expect_one(POLICY_STOP, POLICY_FAULT_MOTION_ENABLE);
    /* The same with play_program: a program, paused. */
    start_with_robot(POLICY_PAUSE, true, POLICY_ROBOT_STILL);
    policy_motion_enable(&p, T0, true, IDLE);
    policy_start_sent(&p, T0 + 1);
    policy_start_kind(&p, false);
    policy_start_answered(&p, T0 + 3);
    policy_motion_enable(&p, T0 + 30, false, IDLE);
    expect_one(POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE);
}

static void blind_after_a_move_stops(void **state)
{
    (void)state;
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_UNKNOWN);
    policy_start_sent(&p, T0 + 1);
    policy_start_kind(&p, true);
    policy_start_answered(&p, T0 + 3);
    check_span(T0 + 10, T0 + LIMIT, MOVING); /* stale: no documents */
    expect_one(POLICY_STOP, POLICY_FAULT_HEARTBEAT);
    /* Blind after a program's start: the configured pause. */
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_UNKNOWN);
    policy_start_sent(&p, T0 + 1);
    policy_start_kind(&p, false);
    policy_start_answered(&p, T0 + 3);
    check_span(T0 + 10, T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
}

static void keep_is_flag_only(void **state)
{
    (void)state;
    start_with_robot(POLICY_KEEP, false, POLICY_ROBOT_MOVING);
    heartbeat_lost_at(T0 + LIMIT + 100, MOVING);
    assert_int_equal(sent.calls, 0);
    assert_int_equal(p.fault, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(p.reaction, POLICY_REACTION_FLAG_ONLY);
    /* Nothing sent, no stop to cancel: the reset passes, the arm moving. */
    char why[48];
    assert_int_equal(policy_may_reset(&p, why, sizeof(why)), 0);
    policy_reset(&p);
    assert_int_equal(p.reaction, POLICY_REACTION_NONE);
}

/* An action lost with its link has no reply to judge it by: the reset
 * waits only for the arm to stand still, never for ever. */
static void reset_after_an_action_lost_with_its_link(void **state)
{
    (void)state;
    char why[48];
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_PROGRAM);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(policy_may_reset(&p, why, sizeof(why)), -EBUSY);
    assert_string_equal(why, "reaction still judged: wait");
    policy_action_unknown(&p, POLICY_PAUSE);
    robot_now = POLICY_ROBOT_MOVING;
    assert_int_equal(policy_may_reset(&p, why, sizeof(why)), -EBUSY);
    assert_string_equal(why, "arm still moving: wait");
    robot_now = POLICY_ROBOT_STILL;
    assert_int_equal(policy_may_reset(&p, why, sizeof(why)), 0);
}

static void reaction_follows_the_status_after_the_reply(void **state)
{
    (void)state;
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_MOVING);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_HEARTBEAT);
    /* Stopped before the reply: not judged until a document after it. */
    robot_now = POLICY_ROBOT_STILL;
    policy_check(&p, T0 + LIMIT + 5, MOVING);
    assert_int_equal(p.reaction, POLICY_REACTION_SENT);
    policy_action_answered(&p, T0 + LIMIT + 6, true);
    policy_check(&p, T0 + LIMIT + 7, MOVING);
    assert_int_equal(p.reaction, POLICY_REACTION_SENT);
    run_span(T0 + LIMIT + 10, T0 + LIMIT + 20, MOVING); /* a document at +20 */
    assert_int_equal(p.reaction, POLICY_REACTION_STOPPED);
    assert_int_equal(sent.calls, 1);
    run_span(T0 + LIMIT + 30, T0 + LIMIT + 500, IDLE);
    assert_int_equal(sent.calls, 1);
    assert_int_equal(p.reaction, POLICY_REACTION_STOPPED);
    /* A program paused reads paused. */
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_PROGRAM);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    expect_one(POLICY_PAUSE, POLICY_FAULT_HEARTBEAT);
    policy_action_answered(&p, T0 + LIMIT + 2, true);
    robot_now = POLICY_ROBOT_PAUSED;
    run_span(T0 + LIMIT + 10, T0 + LIMIT + 20, IDLE);
    assert_int_equal(p.reaction, POLICY_REACTION_PAUSED);
    assert_int_equal(sent.calls, 1);
}

static void still_moving_is_escalated_once(void **state)
{
    (void)state;
    /* A robot that answers but does not stop. */
    start_with_robot(POLICY_PAUSE, false, POLICY_ROBOT_MOVING);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    expect_one(POLICY_STOP, POLICY_FAULT_HEARTBEAT);
    uint64_t answered = T0 + LIMIT + 4;
    policy_action_answered(&p, answered, true);
    run_span(T0 + LIMIT + 10, answered + PERIOD - 1, MOVING);
    assert_int_equal(sent.calls, 1); /* within one period after the reply */
    run_span(answered + PERIOD - 1 + CHECK, answered + PERIOD + CHECK, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(sent.action[1], POLICY_STOP);
    assert_int_equal(p.reaction, POLICY_REACTION_ESCALATED);
    /* The second stop answered, still moving: final, never a third. */
    policy_action_answered(&p, answered + 40, true);
    run_span(answered + 50, answered + 2000, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(p.reaction, POLICY_REACTION_STILL_MOVING);
    assert_int_equal(reactions[reaction_calls - 1], POLICY_REACTION_STILL_MOVING);
    policy_reset(&p);
    assert_int_equal(p.reaction, POLICY_REACTION_NONE);
}

static void escalated_stop_that_works_reads_stopped(void **state)
{
    (void)state;
    start_with_robot(POLICY_STOP, false, POLICY_ROBOT_MOVING);
    heartbeat_lost_at(T0 + LIMIT, MOVING);
    policy_action_answered(&p, T0 + LIMIT + 2, true);
    run_span(T0 + LIMIT + 10, T0 + LIMIT + 60, MOVING);
    assert_int_equal(sent.calls, 2);
    assert_int_equal(p.reaction, POLICY_REACTION_ESCALATED);
    policy_action_answered(&p, T0 + LIMIT + 62, true);
    robot_now = POLICY_ROBOT_STILL;
    run_span(T0 + LIMIT + 70, T0 + LIMIT + 200, IDLE);
    assert_int_equal(p.reaction, POLICY_REACTION_STOPPED);
    assert_int_equal(sent.calls, 2);
}

/*
 * The property: whatever runs, whatever is lost and when, whatever the
 * robot does after the action, (1) a move outside a program that may run
 * is never answered with pause_program alone: the first action is
 * stop_program; (2) an answered action whose status shows the arm still
 * moving one period and a check after the reply is followed by exactly
 * one stop_program more, and the reaction ends still moving, never a
 * third; (3) an arm shown still after the reply ends paused or stopped
 * with nothing more sent.
 */

static void generated_faults_stop_what_moves(void **state)
{
    (void)state;
    unsigned runs = 20000;
    property_seed("policy property", "POLICY_PROPERTY_SEED", runs);
    unsigned acted = 0, stopped_moves = 0, escalated = 0;
    for (unsigned run = 0; run < runs; run++) {
        enum policy_action configured = (enum policy_action)property_next(3);
        bool by_motion_enable = property_next(2);
        enum policy_robot robot = (enum policy_robot)property_next(5);
        bool started = property_next(2), start_is_move = property_next(2);
        unsigned start_at = property_next(LIMIT); /* ms after T0 */
        unsigned after = property_next(3); /* 0 stops, 1 keeps moving, 2 stops after escalation */

        start_with_robot(configured, by_motion_enable, robot);
        if (by_motion_enable)
            policy_motion_enable(&p, T0, true, robot != POLICY_ROBOT_STILL);
        uint64_t t = T0;
        if (started) {
            run_span(T0, T0 + start_at, robot == POLICY_ROBOT_MOVING);
            policy_start_sent(&p, T0 + start_at + 1);
            policy_start_kind(&p, start_is_move);
            policy_start_answered(&p, T0 + start_at + 2);
            t = T0 + start_at + 2;
        }
        bool moving = robot == POLICY_ROBOT_MOVING || robot == POLICY_ROBOT_PROGRAM ||
                      robot == POLICY_ROBOT_UNKNOWN;
        bool unshown = policy_start_unshown(&p, t + 1);
        if (by_motion_enable)
            policy_motion_enable(&p, t + 1, false, moving);
        else
            check_span(t + 1, T0 + start_at + LIMIT + 20, moving);
        bool may_run = moving || unshown;
        bool acts = may_run && (by_motion_enable || configured != POLICY_KEEP);
        if (!acts) {
            if (!may_run)
                assert_int_equal(p.fault, POLICY_FAULT_NONE);
            assert_int_equal(sent.calls, 0);
            continue;
        }
        assert_int_equal(sent.calls, 1);
        acted++;
        bool move_may_run = robot == POLICY_ROBOT_MOVING ||
                            (start_is_move && started &&
                             (robot == POLICY_ROBOT_UNKNOWN ||
                              (robot == POLICY_ROBOT_STILL && unshown) ||
                              (robot == POLICY_ROBOT_PAUSED && unshown)));
        if (move_may_run) {
            assert_int_equal(sent.action[0], POLICY_STOP); /* (1) */
            stopped_moves++;
        }
        /* What the robot does after the action. */
        uint64_t now = p.last_seen_ms;
        robot_now = after == 1 || after == 2 ? POLICY_ROBOT_MOVING
                    : robot == POLICY_ROBOT_PROGRAM && sent.action[0] == POLICY_PAUSE
                        ? POLICY_ROBOT_PAUSED
                        : POLICY_ROBOT_STILL;
        policy_action_answered(&p, now + 1, true);
        for (uint64_t u = now + 2; u <= now + 2 + 3 * PERIOD + 2 * CHECK; u += 1) {
            if (u % PERIOD == 0)
                policy_status_document(&p, u);
            policy_check(&p, u, true);
            if (sent.calls == 2 && p.reaction_answered == false) {
                if (after == 2)
                    robot_now = POLICY_ROBOT_STILL;
                policy_action_answered(&p, u, true);
            }
        }
        if (after == 0) { /* (3) */
            assert_int_equal(sent.calls, 1);
            assert_true(p.reaction == POLICY_REACTION_STOPPED ||
                        p.reaction == POLICY_REACTION_PAUSED);
        } else { /* (2) */
            escalated++;
            assert_int_equal(sent.calls, 2);
            assert_int_equal(sent.action[1], POLICY_STOP);
            assert_int_equal(p.reaction, after == 1 ? POLICY_REACTION_STILL_MOVING
                                                    : POLICY_REACTION_STOPPED);
        }
    }
    printf("policy property: %u acted, %u of them on a move (stop_program), %u escalated\n",
           acted, stopped_moves, escalated);
    /* The generator reaches every rule. */
    assert_true(acted > runs / 4 && stopped_moves > runs / 20 && escalated > runs / 10);
}

/*
 * Braking is stopping, as a property over generated stops: a stopping
 * time S (100..1000 ms), an arm that after the action's reply either
 * brakes to rest over B ms (its step falling linearly to 0), or goes on at
 * its speed, or speeds up. Invariants: (1) an arm at rest within S gets
 * one command and ends paused or stopped, never escalated; (2) an arm
 * that speeds up (a fifth a document) gets the second stop by the second
 * document after the reply and a check, long before S; (3) an arm still moving at S gets it then, not
 * before; (4) a reset is refused while the reaction is judged; (5) a stop
 * the robot refused gets no stopping time: the second one goes out a
 * period after the reply.
 */
static double step_now;

static double fake_step(void *user)
{
    (void)user;
    return step_now;
}

static void braking_is_stopping(void **state)
{
    (void)state;
    unsigned runs = 3000;
    property_seed("braking property", "POLICY_PROPERTY_SEED", runs);
    unsigned rested = 0, sped = 0, long_brakes = 0, refused = 0;
    for (unsigned run = 0; run < runs; run++) {
        uint32_t stop_ms = 100 + property_next(901);
        /* 0 brakes to rest, 1 keeps on, 2 speeds up, 3 refuses the stop */
        unsigned kind = property_next(4);
        uint32_t brake_ms = kind == 0 ? 40 + property_next(stop_ms - 40 + 1)
                                      : stop_ms + 100 + property_next(1000);
        bool program = property_next(2);
        struct policy_config cfg = {.time_limit_ms = LIMIT, .action = POLICY_PAUSE,
                                    .watch = POLICY_WATCH_HEARTBEAT,
                                    .check_period_ms = CHECK, .stop_time_ms = stop_ms};
        struct policy_sink sink = {.send_action = record_action, .robot = fake_robot,
                                   .step = fake_step, .on_reaction = record_reaction,
                                   .user = &sent};
        memset(&sent, 0, sizeof(sent));
        reaction_calls = 0;
        robot_now = program ? POLICY_ROBOT_PROGRAM : POLICY_ROBOT_MOVING;
        step_now = 1.2;
        policy_init(&p, &cfg, &sink);
        for (uint64_t t = T0 - 10 * PERIOD; t <= T0; t += PERIOD)
            policy_status_document(&p, t);
        policy_heartbeat(&p, T0, PLC_A, ADDR_A, 1);
        run_span(T0, T0 + LIMIT, true);
        assert_int_equal(sent.calls, 1);
        assert_int_equal(sent.action[0], program ? POLICY_PAUSE : POLICY_STOP);
        uint64_t answered = T0 + LIMIT + 3;
        policy_action_answered(&p, answered, kind != 3);
        char why[48];
        uint64_t second_at = 0;
        for (uint64_t t = answered + 1; t <= answered + stop_ms + 400; t++) {
            uint64_t since = t - answered;
            if (t % PERIOD == 0) {
                if (kind == 0)
                    step_now = since >= brake_ms ? 0 : 1.2 * (1.0 - (double)since / brake_ms);
                else if (kind == 2)
                    step_now *= 1.2; /* a fifth faster every document */
                robot_now = step_now > 0 ? (program ? POLICY_ROBOT_MOVING : POLICY_ROBOT_MOVING)
                            : program ? POLICY_ROBOT_PAUSED : POLICY_ROBOT_STILL;
                policy_status_document(&p, t);
            }
            if (t % CHECK == 0)
                policy_check(&p, t, true);
            if (sent.calls == 2 && !second_at) {
                second_at = t;
                break;
            }
            if (since == 5 && p.reaction == POLICY_REACTION_SENT)
                assert_int_equal(policy_may_reset(&p, why, sizeof(why)), -EBUSY); /* (4) */
        }
        if (kind == 0) { /* (1) */
            rested++;
            assert_int_equal(sent.calls, 1);
            assert_int_equal(p.reaction, program ? POLICY_REACTION_PAUSED
                                                 : POLICY_REACTION_STOPPED);
            assert_int_equal(policy_may_reset(&p, why, sizeof(why)), 0);
        } else if (kind == 2) { /* (2) */
            sped++;
            assert_int_equal(sent.calls, 2);
            assert_true(second_at - answered <= 2 * PERIOD + 2 * CHECK);
        } else if (kind == 3) { /* (5) */
            refused++;
            assert_int_equal(sent.calls, 2);
            assert_true(second_at - answered <= PERIOD + 2 * CHECK);
        } else { /* (3) */
            long_brakes++;
            assert_int_equal(sent.calls, 2);
            assert_int_equal(sent.action[1], POLICY_STOP);
            assert_true(second_at - answered >= stop_ms + PERIOD);
            assert_true(second_at - answered <= stop_ms + PERIOD + CHECK);
        }
    }
    printf("braking property: %u came to rest within the stopping time, %u sped up, "
           "%u still moved after it, %u refused the stop\n", rested, sped, long_brakes, refused);
    assert_true(rested > runs / 6 && sped > runs / 6 && long_brakes > runs / 6 &&
                refused > runs / 6);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(heartbeat_not_armed_before_a_first_change),
        cmocka_unit_test(pause_becomes_stop_for_a_move_outside_a_program),
        cmocka_unit_test(pause_stays_pause_for_a_program),
        cmocka_unit_test(move_not_shown_yet_is_stopped),
        cmocka_unit_test(blind_after_a_move_stops),
        cmocka_unit_test(keep_is_flag_only),
        cmocka_unit_test(reset_after_an_action_lost_with_its_link),
        cmocka_unit_test(reaction_follows_the_status_after_the_reply),
        cmocka_unit_test(still_moving_is_escalated_once),
        cmocka_unit_test(escalated_stop_that_works_reads_stopped),
        cmocka_unit_test(generated_faults_stop_what_moves),
        cmocka_unit_test(braking_is_stopping),
        cmocka_unit_test(robot_may_move_assumes_the_worst_when_blind),
        cmocka_unit_test(gate_refuses_under_a_fault_and_without_motion_enable),
        cmocka_unit_test(heartbeat_armed_on_first_write),
        cmocka_unit_test(an_action_with_outcome_unknown_is_owed_again),
        cmocka_unit_test(heartbeat_changes_keep_it_alive),
        cmocka_unit_test(same_value_is_not_a_change),
        cmocka_unit_test(loss_while_moving_pauses_once),
        cmocka_unit_test(loss_while_moving_stops_once),
        cmocka_unit_test(keep_sends_nothing_but_latches),
        cmocka_unit_test(loss_while_idle_does_nothing),
        cmocka_unit_test(motion_after_an_idle_loss_acts_once),
        cmocka_unit_test(latched_fault_never_repeats_and_blocks),
        cmocka_unit_test(reset_clears_the_fault),
        cmocka_unit_test(reset_without_a_fault_is_harmless),
        cmocka_unit_test(fault_age_counts_from_the_latch),
        cmocka_unit_test(connection_not_armed_before_a_first_client),
        cmocka_unit_test(connection_lost_counts_from_the_last_close),
        cmocka_unit_test(client_back_in_time_is_no_fault),
        cmocka_unit_test(connection_lost_while_idle_does_nothing),
        cmocka_unit_test(connection_watch_ignores_the_heartbeat),
        cmocka_unit_test(heartbeat_watch_ignores_the_connection),
        cmocka_unit_test(both_watches_either_signal),
        cmocka_unit_test(motion_enable_drop_pauses_at_once),
        cmocka_unit_test(motion_enable_drop_while_idle_latches_nothing),
        cmocka_unit_test(motion_enable_not_required),
        cmocka_unit_test(motion_enable_drop_under_a_latched_fault),
        cmocka_unit_test(drop_after_a_start_not_shown_yet_pauses),
        cmocka_unit_test(starts_unshown_until_the_last_reply_or_the_bound),
        cmocka_unit_test(motion_enable_at_0_pauses_a_later_start),
        cmocka_unit_test(gate_start_while_a_signal_is_lost),
        cmocka_unit_test(several_lost_at_once),
        cmocka_unit_test(an_action_that_cannot_go_out_stays_owed),
        cmocka_unit_test(owner_is_the_heartbeat_writer),
        cmocka_unit_test(owner_released_when_it_disconnects),
        cmocka_unit_test(owner_released_when_its_heartbeat_expires),
        cmocka_unit_test(owner_released_on_expiry_while_latched),
        cmocka_unit_test(no_owner_without_single_owner),
        cmocka_unit_test(sink_without_a_callback),
        cmocka_unit_test(stall_is_the_gateways_fault_not_the_plcs),
        cmocka_unit_test(stall_while_idle_only_reported),
        cmocka_unit_test(stall_seen_by_a_write_first),
        cmocka_unit_test(late_turn_waits_for_its_input),
        cmocka_unit_test(loop_late_on_every_turn_still_judges),
        cmocka_unit_test(stall_judged_with_the_status_read_after_it),
        cmocka_unit_test(owner_host_lets_every_connection_of_the_plc_write),
        cmocka_unit_test(no_start_before_the_heartbeat_changed),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
