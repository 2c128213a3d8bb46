/* SPDX-License-Identifier: MIT */
/*
 * test_events.c - the status page's event log (events.h): each change of
 * the state one event, none at start or twice, a robot gone unknown said
 * once and its values before kept as the reference, the last
 * EVENTS_KEPT kept oldest first.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "events.h"

static struct events e;

static struct events_state running(void)
{
    struct events_state s = {.status_link = 2, .command_link = 2, .handler = 2};
    s.robot = (struct robot_view){.known = true, .powered_on = 1, .enabled = 1, .program = 3,
                                  .emergency_stop = 0, .protective_stop = 0, .mode = 2,
                                  .speed_override = 1};
    return s;
}

static const char *text(unsigned i)
{
    return events_get(&e, i)->text;
}

static void has(const char *what)
{
    for (unsigned i = 0; i < events_count(&e); i++)
        if (strcmp(text(i), what) == 0)
            return;
    fail_msg("no event \"%s\" among %u", what, events_count(&e));
}

static void changes_are_events_once(void **state)
{
    (void)state;
    memset(&e, 0, sizeof(e));
    struct events_state s = running();
    events_update(&e, &s);
    unsigned first = events_count(&e);
    has("status link: connected");
    has("program: running");
    events_update(&e, &s);
    assert_int_equal(events_count(&e), first); /* nothing changed */
    s.fault = 1;
    s.robot.program = 2;
    events_update(&e, &s);
    has("fault 1 latched: PLC heartbeat lost");
    has("program: paused");
    assert_string_equal(events_get(&e, events_count(&e) - 1)->kind, "robot");
    s.fault = 0;
    strcpy(s.owner, "192.0.2.7");
    events_update(&e, &s);
    has("fault 1 (PLC heartbeat lost) reset by the PLC");
    has("write owner: 192.0.2.7");
    for (unsigned i = 1; i < events_count(&e); i++)
        assert_true(events_get(&e, i)->seq == events_get(&e, i - 1)->seq + 1);
}

static void unknown_is_said_once_and_a_return_logs_only_changes(void **state)
{
    (void)state;
    memset(&e, 0, sizeof(e));
    struct events_state s = running();
    events_update(&e, &s);
    unsigned before = events_count(&e);
    struct events_state stale = s;
    stale.status_link = 3;
    stale.robot = (struct robot_view){.powered_on = -1, .enabled = -1, .program = -1,
                                      .emergency_stop = -1, .protective_stop = -1,
                                      .mode = -1, .speed_override = NAN};
    events_update(&e, &stale);
    events_update(&e, &stale);
    assert_int_equal(events_count(&e), before + 2);
    has("status link: connected, but silent (status stale)");
    has("robot state unknown (no fresh status)");
    /* Back with the program paused meanwhile: that, not every value. */
    s.robot.program = 2;
    events_update(&e, &s);
    assert_int_equal(events_count(&e), before + 4);
    assert_string_equal(text(events_count(&e) - 1), "program: paused");
}

static void the_last_ones_are_kept_oldest_first(void **state)
{
    (void)state;
    memset(&e, 0, sizeof(e));
    struct events_state s = running();
    for (unsigned i = 0; i < 3 * EVENTS_KEPT; i++) {
        s.motion_enabled = (int)(i % 2);
        events_update(&e, &s);
    }
    assert_int_equal(events_count(&e), EVENTS_KEPT);
    assert_int_equal(events_get(&e, EVENTS_KEPT - 1)->seq, e.seq);
    assert_int_equal(events_get(&e, 0)->seq, e.seq - EVENTS_KEPT + 1);
    assert_null(events_get(&e, EVENTS_KEPT));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(changes_are_events_once),
        cmocka_unit_test(unknown_is_said_once_and_a_return_logs_only_changes),
        cmocka_unit_test(the_last_ones_are_kept_oldest_first),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
