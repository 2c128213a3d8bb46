/* SPDX-License-Identifier: MIT */
/*
 * test_sim_ramp.c - jakasim's acceleration and braking profile
 * (sim/ramp.h): what the gateway's stopping-time judgement relies on. A
 * move speeds up and slows down at the ramp's rate and arrives with every
 * joint at once; a program's braking covers v0 T / 2 and ends within the
 * stopping time.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>

#include "../sim/ramp.c"

/* No stopping time: the full speed at once, and 0 at once when halting. */
static void no_stopping_time_is_no_ramp(void **state)
{
    (void)state;
    struct sim_ramp m = {0};
    assert_true(sim_ramp_speed(&m, 40, 0.5, 100, 0.008) == 20);
    m.halting = SIM_HALT_STOP;
    assert_true(sim_ramp_speed(&m, 40, 0.5, 100, 0.008) == 0);
}

/* A joint move: it speeds up no faster than the rate allows; every joint
 * arrives in the same tick, and the speed is low by then. */
static void a_move_ramps_up_and_down(void **state)
{
    (void)state;
    struct sim_ramp m = {.stop_time_s = 0.4};
    double joints[SIM_JOINTS] = {0, 90, 90, 0, 90, 0};
    const double target[SIM_JOINTS] = {30, 80, 100, 5, 90, -10};
    double accel = 60 / 0.4, last = 0, top = 0;
    unsigned ticks = 0;

    while (!sim_ramp_move_joints(&m, joints, target, 60, 1, 0.008)) {
        assert_true(m.path_speed - last <= accel * 0.008 + 1e-9);
        last = m.path_speed;
        top = fmax(top, last);
        assert_true(++ticks < 10000);
    }
    for (int i = 0; i < SIM_JOINTS; i++)
        assert_true(joints[i] == target[i]);
    assert_true(top > 50 && top <= 60); /* it got up to speed */
    assert_true(m.path_speed <= accel * 0.008 * 3); /* and came down to arrive */
}

/* A program braked from v0: v0 T / 2 covered, at rest after T. */
static void braking_covers_half_of_v0_t(void **state)
{
    (void)state;
    struct sim_ramp m = {.stop_time_s = 0.5};
    double joints[SIM_JOINTS] = {0};
    const double vel[SIM_JOINTS] = {20, -10, 0, 5, 40, -40};
    double t = 0;

    sim_ramp_brake(&m, vel);
    assert_true(m.braking);
    while (!sim_ramp_brake_tick(&m, joints, 0.03)) {
        t += 0.03;
        assert_true(t < 0.5);
    }
    assert_false(m.braking);
    for (int i = 0; i < SIM_JOINTS; i++)
        assert_true(fabs(joints[i] - vel[i] * 0.5 / 2) < 1e-9);

    struct sim_ramp none = {0};
    sim_ramp_brake(&none, vel);
    assert_false(none.braking); /* no stopping time: at rest at once */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(no_stopping_time_is_no_ramp),
        cmocka_unit_test(a_move_ramps_up_and_down),
        cmocka_unit_test(braking_covers_half_of_v0_t),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
