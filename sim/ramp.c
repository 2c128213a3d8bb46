/* SPDX-License-Identifier: MIT */
/* ramp.c - jakasim's acceleration and braking profile (ramp.h). */
#include "ramp.h"

#include <math.h>
#include <string.h>

double sim_ramp_speed(const struct sim_ramp *m, double full_speed, double rate,
                      double remaining, double dt)
{
    double want = m->halting != SIM_HALT_NONE ? 0 : full_speed * rate;

    if (m->stop_time_s <= 0)
        return want;
    double accel = full_speed / m->stop_time_s;
    double v = m->path_speed;
    v = v < want ? fmin(v + accel * dt, want) : fmax(v - accel * dt, want);
    /* The speed from which it still stops within 'remaining': v^2 = 2 a s. */
    return fmin(v, sqrt(2 * accel * remaining));
}

bool sim_ramp_move_joints(struct sim_ramp *m, double joints[SIM_JOINTS],
                          const double target[SIM_JOINTS], double full_speed, double rate,
                          double dt)
{
    double remaining = 0;

    for (int i = 0; i < SIM_JOINTS; i++)
        remaining = fmax(remaining, fabs(target[i] - joints[i]));
    if (remaining <= 1e-9)
        return true;
    m->path_speed = sim_ramp_speed(m, full_speed, rate, remaining, dt);
    double step = fmin(m->path_speed * dt, remaining);
    for (int i = 0; i < SIM_JOINTS; i++)
        joints[i] = step >= remaining ? target[i]
                                      : joints[i] + (target[i] - joints[i]) * step / remaining;
    return step >= remaining;
}

void sim_ramp_brake(struct sim_ramp *m, const double joint_vel[SIM_JOINTS])
{
    if (m->stop_time_s <= 0)
        return;
    memcpy(m->brake_vel, joint_vel, sizeof(m->brake_vel));
    m->brake_total_s = m->brake_left_s = m->stop_time_s;
    m->braking = true;
}

bool sim_ramp_brake_tick(struct sim_ramp *m, double joints[SIM_JOINTS], double dt)
{
    double total = m->brake_total_s, t1 = total - m->brake_left_s;
    double t2 = fmin(total, t1 + dt);
    /* The integral of 1 - t / T from t1 to t2: the share of v0 covered. */
    double share = (t2 - t1) - (t2 * t2 - t1 * t1) / (2 * total);

    for (int i = 0; i < SIM_JOINTS; i++)
        joints[i] += m->brake_vel[i] * share;
    m->brake_left_s -= dt;
    if (m->brake_left_s > 0)
        return false;
    m->braking = false;
    return true;
}
