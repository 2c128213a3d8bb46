/* SPDX-License-Identifier: MIT */
/* robot.c - see robot.h. */
#include "robot.h"

#include "json_member.h"

#include "status_doc.h"

#include <cJSON.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#define DEG (M_PI / 180.0)
/* A controller's errorMsg for errorCode "1". */
#define CALL_FAILED "Exception:function call failed"

/* ---- kinematics ---- */

/* Modified-UR DH of a 5 kg JAKA arm: d1, a2, a3, d4, d5, d6 in mm. */
static const double dh_d[6] = {120.15, 0, 0, 114.5, 113.5, 107.0};
static const double dh_a[6] = {0, 0, 430.0, 368.5, 0, 0};
static const double dh_alpha[6] = {0, M_PI / 2, 0, 0, M_PI / 2, -M_PI / 2};

static void mat_mul(const double a[16], const double b[16], double out[16])
{
    double t[16];
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            t[4 * i + j] = 0;
            for (int k = 0; k < 4; k++)
                t[4 * i + j] += a[4 * i + k] * b[4 * k + j];
        }
    memcpy(out, t, sizeof(t));
}

void sim_forward_kinematics(const double joints[SIM_JOINTS], double pose[6])
{
    double T[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

    for (int i = 0; i < 6; i++) {
        /* Craig's modified DH: Rx(alpha) Tx(a) Rz(theta) Tz(d). */
        double ca = cos(dh_alpha[i]), sa = sin(dh_alpha[i]);
        double ct = cos(joints[i] * DEG), st = sin(joints[i] * DEG);
        double A[16] = {ct,      -st,     0,   dh_a[i],
                        st * ca, ct * ca, -sa, -sa * dh_d[i],
                        st * sa, ct * sa, ca,  ca * dh_d[i],
                        0,       0,       0,   1};
        mat_mul(T, A, T);
    }
    pose[0] = T[3];
    pose[1] = T[7];
    pose[2] = T[11];
    /* Fixed-axis XYZ (roll, pitch, yaw), in degrees. */
    pose[4] = atan2(-T[8], sqrt(T[0] * T[0] + T[4] * T[4])) / DEG;
    pose[5] = atan2(T[4], T[0]) / DEG;
    pose[3] = atan2(T[9], T[10]) / DEG;
}

static double wrap180(double a)
{
    while (a > 180)
        a -= 360;
    while (a < -180)
        a += 360;
    return a;
}

static void pose_error(const double want[6], const double have[6], double err[6])
{
    for (int i = 0; i < 3; i++)
        err[i] = want[i] - have[i];
    /* Angles weigh like 1 mm per 0.1 deg so both converge together. */
    for (int i = 3; i < 6; i++)
        err[i] = wrap180(want[i] - have[i]) * 10;
}

/* Damped least squares on a numerical Jacobian. */
bool sim_inverse_kinematics(const double pose[6], const double seed[SIM_JOINTS],
                            double joints[SIM_JOINTS])
{
    double q[6], have[6], err[6];

    memcpy(q, seed, sizeof(q));
    for (int iter = 0; iter < 200; iter++) {
        double J[6][6], norm = 0;
        sim_forward_kinematics(q, have);
        pose_error(pose, have, err);
        for (int i = 0; i < 6; i++)
            norm += err[i] * err[i];
        if (norm < 1e-6) {
            for (int i = 0; i < 6; i++)
                joints[i] = wrap180(q[i]);
            return true;
        }
        for (int j = 0; j < 6; j++) {
            double qd[6], pd[6], e2[6];
            memcpy(qd, q, sizeof(qd));
            qd[j] += 1e-4;
            sim_forward_kinematics(qd, pd);
            pose_error(pose, pd, e2);
            for (int i = 0; i < 6; i++)
                J[i][j] = (err[i] - e2[i]) / 1e-4;
        }
        /* Solve (J^T J + l^2 I) dq = J^T err by Gaussian elimination. */
        double A[6][7];
        for (int r = 0; r < 6; r++) {
            for (int c = 0; c < 6; c++) {
                A[r][c] = r == c ? 0.01 : 0;
                for (int k = 0; k < 6; k++)
                    A[r][c] += J[k][r] * J[k][c];
            }
            A[r][6] = 0;
            for (int k = 0; k < 6; k++)
                A[r][6] += J[k][r] * err[k];
        }
        for (int p = 0; p < 6; p++) {
            int best = p;
            for (int r = p + 1; r < 6; r++)
                if (fabs(A[r][p]) > fabs(A[best][p]))
                    best = r;
            for (int c = 0; c < 7; c++) {
                double t = A[p][c];
                A[p][c] = A[best][c];
                A[best][c] = t;
            }
            if (fabs(A[p][p]) < 1e-12)
                return false;
            for (int r = 0; r < 6; r++) {
                if (r == p)
                    continue;
                double f = A[r][p] / A[p][p];
                for (int c = p; c < 7; c++)
                    A[r][c] -= f * A[p][c];
            }
        }
        for (int i = 0; i < 6; i++) {
            double step = A[i][6] / A[i][i];
            if (step > 10)
                step = 10;
            if (step < -10)
                step = -10;
            q[i] += step;
        }
    }
    return false;
}

/* ---- state ---- */

void sim_robot_init(struct sim_robot *r, bool test_pattern)
{
    static const double home[SIM_JOINTS] = {0, 90, 90, 0, 90, 0};

    memset(r, 0, sizeof(*r));
    memcpy(r->joints, home, sizeof(home));
    memcpy(r->joint_cmd, home, sizeof(home));
    memcpy(r->joint_target, home, sizeof(home));
    sim_forward_kinematics(r->joints, r->cart);
    r->rapid_rate = 1.0;
    r->payload_mass = 1.0;
    r->payload_centroid[2] = 1.0;
    r->collision_level = 3;
    r->tio_ain[0] = r->tio_ain[1] = 474.0;
    snprintf(r->errcode, sizeof(r->errcode), "0x0");
    r->test_pattern = test_pattern;
    if (test_pattern) {
        for (int i = 0; i < SIM_MAX_DIO; i++) {
            r->din[i] = (i * 7 + 3) % 5 < 2;
            r->dout[i] = (i * 3 + 1) % 4 == 0;
        }
        for (int i = 0; i < SIM_MAX_AIO; i++) {
            r->ain[i] = 0.25 + i * 1.5;
            r->aout[i] = -3.75 + i * 0.5;
        }
        for (int i = 0; i < 8; i++) {
            r->tio_din[i] = i % 3 == 1;
            r->tio_dout[i] = i % 2 == 0;
        }
        for (int i = 0; i < SIM_EXTIO_DO; i++)
            r->extio_do[i] = (i + 1) % 3 == 0;
        for (int i = 0; i < SIM_EXTIO_AO; i++)
            r->extio_ao[i] = 4300.5 + i;
        r->tio_ain[0] = 466.0;
        r->tio_ain[1] = 469.5;
        r->rapid_rate = 0.625;
        r->tool_id = 3;
        r->user_id = 2;
        snprintf(r->errcode, sizeof(r->errcode), "0x2b0c0001");
        snprintf(r->errmsg, sizeof(r->errmsg),
                 "test pattern: joint 3 \"soft\" limit, {braces} and a \\ backslash");
    }
}

/* How far apart two poses are for a linear move: mm of the position, or
 * degrees of the largest turn of an angle when that is the larger. */
static double pose_distance(const double a[6], const double b[6])
{
    double mm = 0, deg = 0;
    for (int i = 0; i < 3; i++)
        mm += (b[i] - a[i]) * (b[i] - a[i]);
    for (int i = 3; i < 6; i++)
        if (fabs(wrap180(b[i] - a[i])) > deg)
            deg = fabs(wrap180(b[i] - a[i]));
    return fmax(sqrt(mm), deg);
}

/* The arm holds where it is at once (power gone, an emergency stop): no
 * move, none waiting to start. */
static void halt_arm(struct sim_robot *r)
{
    r->moving = false;
    r->linear = false;
    r->queued_count = 0;
    r->ramp.halting = SIM_HALT_NONE;
    r->ramp.path_speed = 0;
    r->ramp.braking = false;
    memcpy(r->joint_target, r->joints, sizeof(r->joints));
    memcpy(r->joint_cmd, r->joints, sizeof(r->joints));
}

/* A stop of a move: nothing queued starts, and the move under way slows
 * down to a standstill where it is (at once with no stopping time). */
static void stop_arm(struct sim_robot *r)
{
    r->queued_count = 0;
    if (r->ramp.stop_time_s <= 0 || !r->moving || r->ramp.path_speed <= 0) {
        halt_arm(r);
        return;
    }
    r->ramp.halting = SIM_HALT_STOP;
}

/* A program stopped or paused: every joint slows down from its speed of
 * the last tick to 0 within the stopping time (at once with none). */
static void brake_program(struct sim_robot *r)
{
    memcpy(r->joint_target, r->joints, sizeof(r->joints));
    memcpy(r->joint_cmd, r->joints, sizeof(r->joints));
    sim_ramp_brake(&r->ramp, r->joint_vel);
}

/* The first move queued starts now. */
static void start_next_move(struct sim_robot *r)
{
    const struct sim_move *next = &r->queued[0];

    memcpy(r->joint_target, next->target, sizeof(r->joint_target));
    memcpy(r->joint_cmd, next->target, sizeof(r->joint_cmd));
    r->joint_speed = next->speed;
    r->linear = next->linear;
    if (r->linear) {
        memcpy(r->lin_start, r->cart, sizeof(r->lin_start));
        memcpy(r->lin_target, next->pose, sizeof(r->lin_target));
        r->lin_length = pose_distance(r->lin_start, r->lin_target);
        r->lin_done = 0;
    }
    r->moving = true;
    r->ramp.path_speed = 0;
    r->ramp.halting = SIM_HALT_NONE;
    r->queued_count--;
    memmove(&r->queued[0], &r->queued[1], r->queued_count * sizeof(r->queued[0]));
}

/* Joint speed, TCP speed and the pose after the joints moved from 'before'. */
static void track_motion(struct sim_robot *r, const double before[SIM_JOINTS], double dt)
{
    double cart_before[6], dist = 0;

    memcpy(cart_before, r->cart, sizeof(cart_before));
    for (int i = 0; i < SIM_JOINTS; i++)
        r->joint_vel[i] = dt > 0 ? (r->joints[i] - before[i]) / dt : 0;
    sim_forward_kinematics(r->joints, r->cart);
    for (int i = 0; i < 3; i++)
        dist += (r->cart[i] - cart_before[i]) * (r->cart[i] - cart_before[i]);
    r->tcp_speed = dt > 0 ? sqrt(dist) / dt : 0;
}

static bool move_joints(struct sim_robot *r, double dt)
{
    double max_step = r->joint_speed * r->rapid_rate * dt;
    bool arrived = true;
    double before[SIM_JOINTS];

    memcpy(before, r->joints, sizeof(before));
    for (int i = 0; i < SIM_JOINTS; i++) {
        double d = r->joint_target[i] - r->joints[i];
        double step = fabs(d) <= max_step ? d : (d > 0 ? max_step : -max_step);
        r->joints[i] += step;
        if (fabs(r->joint_target[i] - r->joints[i]) > 1e-9)
            arrived = false;
    }
    track_motion(r, before, dt);
    return arrived;
}

/* A joint move for one tick, at the ramped speed (ramp.h). */
static bool move_joints_ramped(struct sim_robot *r, double dt)
{
    double before[SIM_JOINTS];

    memcpy(before, r->joints, sizeof(before));
    bool arrived = sim_ramp_move_joints(&r->ramp, r->joints, r->joint_target, r->joint_speed,
                                        r->rapid_rate, dt);
    track_motion(r, before, dt);
    return arrived;
}

/*
 * moveL: the TCP goes along the straight line at the move's speed (mm/s,
 * or deg/s for a turn longer in degrees than the travel in mm), every
 * angle turning in proportion; the joints are the inverse solution of each
 * point, from the last. A point with no solution ends the move there.
 */
static bool move_linear(struct sim_robot *r, double dt)
{
    double before[SIM_JOINTS], pose[6], q[SIM_JOINTS];
    double frac;

    memcpy(before, r->joints, sizeof(before));
    r->ramp.path_speed = sim_ramp_speed(&r->ramp, r->joint_speed, r->rapid_rate,
                                        fmax(r->lin_length - r->lin_done, 0), dt);
    r->lin_done += r->ramp.path_speed * dt;
    frac = r->lin_length <= 0 || r->lin_done >= r->lin_length ? 1 : r->lin_done / r->lin_length;
    for (int i = 0; i < 3; i++)
        pose[i] = r->lin_start[i] + (r->lin_target[i] - r->lin_start[i]) * frac;
    for (int i = 3; i < 6; i++)
        pose[i] = wrap180(r->lin_start[i] + wrap180(r->lin_target[i] - r->lin_start[i]) * frac);
    if (!sim_inverse_kinematics(pose, r->joints, q)) {
        halt_arm(r);
        return true;
    }
    memcpy(r->joints, q, sizeof(q));
    track_motion(r, before, dt);
    if (frac < 1)
        return false;
    memcpy(r->joint_target, r->joints, sizeof(r->joint_target));
    memcpy(r->joint_cmd, r->joints, sizeof(r->joint_cmd));
    return true;
}

/* One tick of a program's braking (ramp.h); at rest, the arm holds there. */
static void brake_tick(struct sim_robot *r, double dt)
{
    double before[SIM_JOINTS];

    memcpy(before, r->joints, sizeof(before));
    bool at_rest = sim_ramp_brake_tick(&r->ramp, r->joints, dt);
    track_motion(r, before, dt);
    if (at_rest) {
        memcpy(r->joint_target, r->joints, sizeof(r->joint_target));
        memcpy(r->joint_cmd, r->joints, sizeof(r->joint_cmd));
    }
}

/* A move under way for one tick; a stop ends it once it stands still. */
static void advance_move(struct sim_robot *r, double dt)
{
    if (r->linear ? move_linear(r, dt) : move_joints_ramped(r, dt)) {
        r->moving = false;
        r->linear = false;
        r->ramp.halting = SIM_HALT_NONE;
        r->ramp.path_speed = 0;
    } else if (r->ramp.halting == SIM_HALT_STOP && r->ramp.path_speed <= 0) {
        /* At rest: the move ends here. Moves accepted while it braked
         * (after the stop) stay queued and run next. */
        unsigned queued = r->queued_count;
        halt_arm(r);
        r->queued_count = queued;
    }
}

void sim_robot_tick(struct sim_robot *r, double dt)
{
    if (r->interp_state != 2)
        r->paused_move = false; /* power_off, disable or play ended it */
    r->uptime_s += dt;
    memset(r->joint_vel, 0, sizeof(r->joint_vel));
    r->tcp_speed = 0;
    /* Power gone or an emergency stop ends a move outside a program where
     * the arm is; a protective stop brings it to a standstill. */
    if ((!r->enabled || r->emergency_stop) && (r->moving || r->queued_count > 0) &&
        r->interp_state != 3)
        halt_arm(r);
    if (r->protective_stop && (r->moving || r->queued_count > 0) && r->interp_state != 3 &&
        r->ramp.halting != SIM_HALT_STOP)
        stop_arm(r);
    if (!r->enabled) {
        r->moving = false;
        r->ramp.braking = false;
        if (r->interp_state == 3 || r->interp_state == 2)
            r->interp_state = 0;
        return;
    }
    if (r->ramp.braking) {
        brake_tick(r, dt);
        return;
    }
    if (r->interp_state == 3) {
        /* A loaded program sways every joint around home. */
        static const double home[SIM_JOINTS] = {0, 90, 90, 0, 90, 0};
        r->program_time += dt * r->rapid_rate;
        for (int i = 0; i < SIM_JOINTS; i++)
            r->joint_target[i] = home[i] + 15 * sin(0.8 * r->program_time + i);
        r->joint_speed = 60;
        move_joints(r, dt);
        memcpy(r->joint_cmd, r->joint_target, sizeof(r->joint_cmd));
        return;
    }
    if (r->interp_state == 2) {
        /* Paused: nothing starts; a paused move slows down to rest. */
        if (r->paused_move && r->moving && r->ramp.path_speed > 0)
            advance_move(r, dt);
        return;
    }
    /* The next move starts once the arm is free and its lag has passed;
     * every queued move's lag runs meanwhile. */
    if (!r->moving && r->queued_count > 0 && r->queued[0].lag_left == 0)
        start_next_move(r);
    for (unsigned i = 0; i < r->queued_count; i++)
        if (r->queued[i].lag_left > 0)
            r->queued[i].lag_left--;
    if (r->moving)
        advance_move(r, dt);
}

/* ---- commands ---- */

struct command_ctx {
    struct sim_robot *r;
    const cJSON *req;
    const char *name;
    struct pyjson *w;
};

/*
 * A reply of text members in exactly the order given, as key, value pairs
 * ending with NULL: the manual's replies do not all share one order.
 */
static bool reply_in_order(struct pyjson *w, const char *const *pairs)
{
    pyjson_begin_object(w);
    for (; pairs[0]; pairs += 2) {
        pyjson_key(w, pairs[0]);
        pyjson_string(w, pairs[1]);
    }
    pyjson_end_object(w);
    return true;
}

/* Starts a reply the common way: errorCode, errorMsg, cmdName. */
static void reply_head(struct command_ctx *c, const char *code, const char *msg,
                       const char *cmd_name)
{
    pyjson_begin_object(c->w);
    pyjson_key(c->w, "errorCode");
    pyjson_string(c->w, code);
    pyjson_key(c->w, "errorMsg");
    pyjson_string(c->w, msg);
    pyjson_key(c->w, "cmdName");
    pyjson_string(c->w, cmd_name);
}

static bool reply_ok(struct command_ctx *c)
{
    reply_head(c, "0", "", c->name);
    pyjson_end_object(c->w);
    return true;
}

/* An OK reply with one more member, already formatted as JSON ('raw'). */
static bool reply_ok_member(struct command_ctx *c, const char *key, const char *raw)
{
    reply_head(c, "0", "", c->name);
    pyjson_key(c->w, key);
    pyjson_raw(c->w, raw);
    pyjson_end_object(c->w);
    return true;
}

/* An OK reply with one more text member. */
static bool reply_ok_text(struct command_ctx *c, const char *key, const char *value)
{
    struct pyjson text;
    pyjson_init(&text);
    pyjson_string(&text, value);
    bool ok = reply_ok_member(c, key, text.failed ? "\"\"" : text.buf);
    pyjson_free(&text);
    return ok;
}

static bool reply_refused(struct command_ctx *c, const char *why)
{
    reply_head(c, "2", why, c->name);
    pyjson_end_object(c->w);
    return true;
}

static bool call_failed(struct command_ctx *c)
{
    char msg[96];
    snprintf(msg, sizeof(msg), "call %s failed", c->name);
    return reply_refused(c, msg);
}

static bool get_number(const cJSON *req, const char *key, double *out)
{
    const cJSON *v = json_member_last(req, key);
    if (!cJSON_IsNumber(v))
        return false;
    *out = v->valuedouble;
    return true;
}

static bool get_vector(const cJSON *req, const char *key, double *out, int n)
{
    const cJSON *v = json_member_last(req, key);
    if (!cJSON_IsArray(v) || cJSON_GetArraySize(v) < n)
        return false;
    for (int i = 0; i < n; i++) {
        const cJSON *e = cJSON_GetArrayItem(v, i);
        if (!cJSON_IsNumber(e))
            return false;
        out[i] = e->valuedouble;
    }
    return true;
}

/* Reads member 'key' as a number within [min, max]. */
static bool get_bounded(const cJSON *req, const char *key, double min, double max,
                        double *out)
{
    return get_number(req, key, out) && *out >= min && *out <= max;
}

static bool can_move(struct command_ctx *c)
{
    return c->r->powered_on && c->r->enabled && !c->r->emergency_stop &&
           !c->r->protective_stop && c->r->interp_state != 3;
}

/*
 * Accepts a move: it starts once the moves before it have ended, and no
 * sooner than move_lag_ticks ticks from now (the status documents until
 * then still show the arm in position where it was). 'pose' (NULL: a
 * joint move) makes it a linear one through that pose, 'speed' then in
 * mm/s. A relative target was taken from where the arm is now.
 */
static bool accept_move(struct command_ctx *c, const double target[6], double speed,
                        const double *pose)
{
    struct sim_robot *r = c->r;
    if (!can_move(c) || speed <= 0)
        return call_failed(c);
    if (r->queued_count == SIM_MOVE_QUEUE)
        return reply_refused(c, "too many moves queued");
    struct sim_move *m = &r->queued[r->queued_count++];
    memcpy(m->target, target, sizeof(m->target));
    m->speed = speed;
    m->linear = pose != NULL;
    if (pose)
        memcpy(m->pose, pose, sizeof(m->pose));
    m->lag_left = r->move_lag_ticks;
    return reply_ok(c);
}

static bool start_joint_move(struct command_ctx *c, const double target[6], double speed)
{
    return accept_move(c, target, speed, NULL);
}

static bool cmd_power_on(struct command_ctx *c)
{
    if (c->r->emergency_stop)
        return reply_refused(c, "emergency stop is triggered");
    c->r->powered_on = true;
    reply_head(c, "0", "", c->name);
    /* The manual's reply carries this extra member, with a space. */
    pyjson_key(c->w, "power status");
    pyjson_string(c->w, "True");
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_power_off(struct command_ctx *c)
{
    c->r->powered_on = false;
    c->r->enabled = false;
    halt_arm(c->r);
    c->r->interp_state = 0;
    return reply_ok(c);
}

static bool cmd_enable(struct command_ctx *c)
{
    if (!c->r->powered_on)
        return reply_refused(c, "robot is powered off");
    if (c->r->emergency_stop)
        return reply_refused(c, "emergency stop is triggered");
    c->r->enabled = true;
    return reply_in_order(c->w, (const char *const[]){"errorCode", "0", "enabled status",
                                                      "True", "cmdName", c->name,
                                                      "errorMsg", "", NULL});
}

static bool cmd_disable(struct command_ctx *c)
{
    c->r->enabled = false;
    halt_arm(c->r);
    return reply_ok(c);
}

static bool cmd_joint_move(struct command_ctx *c)
{
    double target[6], speed, rel = 0;
    if (!get_vector(c->req, "jointPosition", target, 6) ||
        !get_number(c->req, "speed", &speed))
        return call_failed(c);
    get_number(c->req, "relFlag", &rel);
    if (rel != 0)
        for (int i = 0; i < 6; i++)
            target[i] += c->r->joints[i];
    return start_joint_move(c, target, speed);
}

/* A move to a TCP pose: along a straight line ('linear', speed in mm/s),
 * or a joint move to its inverse solution (speed in deg/s). */
static bool cartesian_move(struct command_ctx *c, const char *key, bool linear)
{
    double pose[6], joints[6], speed, rel = 0;
    if (!get_vector(c->req, key, pose, 6) || !get_number(c->req, "speed", &speed))
        return call_failed(c);
    get_number(c->req, "relFlag", &rel);
    if (rel != 0)
        for (int i = 0; i < 6; i++)
            pose[i] += c->r->cart[i];
    if (!sim_inverse_kinematics(pose, c->r->joints, joints))
        return call_failed(c);
    for (int i = 3; i < 6; i++)
        pose[i] = wrap180(pose[i]);
    return accept_move(c, joints, speed, linear ? pose : NULL);
}

/* 4.8: the inverse solution, reached by a joint move (speed in deg/s). */
static bool cmd_end_move(struct command_ctx *c)
{
    return cartesian_move(c, "endPosition", false);
}

/* 4.9: a straight line, speed in mm/s. */
static bool cmd_move_l(struct command_ctx *c)
{
    return cartesian_move(c, "cartPosition", true);
}

/* movc's arc is simulated as a straight line to its end. */
static bool cmd_movc(struct command_ctx *c)
{
    return cartesian_move(c, "pos_end", true);
}

/* 4.66: "a movement instruction": the arm moves to jointPosition. */
static bool cmd_start_payload_identify(struct command_ctx *c)
{
    double target[6];
    if (!get_vector(c->req, "jointPosition", target, 6))
        return call_failed(c);
    return start_joint_move(c, target, 30);
}

static bool cmd_jog(struct command_ctx *c)
{
    double mode = -1, coord = -1, jnum = -1, vel = 0, pos = 0;
    get_number(c->req, "jog_mode", &mode);
    get_number(c->req, "coord_map", &coord);
    get_number(c->req, "jnum", &jnum);
    get_number(c->req, "jogvel", &vel);
    get_number(c->req, "poscmd", &pos);
    if (mode < 0 || mode > 3 || jnum < 0 || jnum > 5)
        return call_failed(c);
    if (mode == 0) {
        stop_arm(c->r);
        return reply_ok(c);
    }
    if (coord != 1)
        return reply_refused(c, "jog: only joint space is simulated");
    double target[6];
    memcpy(target, c->r->joints, sizeof(target));
    int j = (int)jnum;
    if (mode == 1)
        target[j] += vel >= 0 ? 360 : -360;
    else if (mode == 2)
        target[j] += vel < 0 ? -fabs(pos) : pos;
    else
        target[j] = pos;
    return start_joint_move(c, target, fabs(vel));
}

static bool cmd_get_robot_state(struct command_ctx *c)
{
    return reply_in_order(
        c->w, (const char *const[]){"cmdName", c->name, "errorCode", "0", "errorMsg", "unknown",
                                    "enable", c->r->enabled ? "robot_enabled" : "robot_disabled",
                                    "power", c->r->powered_on ? "powered_on" : "powered_off",
                                    NULL});
}

/*
 * The whole status document, as port 10000 would push it now, as the
 * reply's "data" member: several kilobytes, more than one read of the
 * command port.
 */
static bool cmd_get_data(struct command_ctx *c)
{
    const struct sim_profile *p = c->r->profile ? c->r->profile : sim_profile_find("full");
    struct pyjson doc;

    pyjson_init(&doc);
    sim_status_document(&doc, c->r, p, 0);
    reply_head(c, "0", "", c->name);
    pyjson_key(c->w, "data");
    pyjson_raw(c->w, doc.failed ? "{}" : doc.buf);
    pyjson_end_object(c->w);
    pyjson_free(&doc);
    return true;
}

static bool cmd_servo_move(struct command_ctx *c)
{
    double flag = 0;
    if (!get_number(c->req, "relFlag", &flag) || !c->r->enabled)
        return call_failed(c);
    c->r->servo_mode = flag != 0;
    return reply_ok(c);
}

static bool cmd_is_in_servomove(struct command_ctx *c)
{
    return reply_ok_member(c, "in_servomove", c->r->servo_mode ? "true" : "false");
}

static bool cmd_servo_j(struct command_ctx *c)
{
    double q[6], rel = 0;
    if (!c->r->servo_mode) {
        reply_head(c, "-1", "servoj command can only be excuted in servo move mode",
                   c->name);
        pyjson_end_object(c->w);
        return true;
    }
    if (!get_vector(c->req, "jointPosition", q, 6))
        return call_failed(c);
    get_number(c->req, "relFlag", &rel);
    for (int i = 0; i < 6; i++) {
        double target = rel != 0 ? c->r->joints[i] + q[i] : q[i];
        /* 180 deg/s in an 8 ms cycle: larger steps are ignored. */
        if (fabs(target - c->r->joints[i]) > 180 * 0.008)
            return reply_ok(c);
        q[i] = target;
    }
    memcpy(c->r->joints, q, sizeof(q));
    memcpy(c->r->joint_cmd, q, sizeof(q));
    memcpy(c->r->joint_target, q, sizeof(q));
    sim_forward_kinematics(c->r->joints, c->r->cart);
    return reply_ok(c);
}

static bool cmd_rapid_rate(struct command_ctx *c)
{
    double v;
    if (!get_bounded(c->req, "rate_value", 0, 1, &v))
        return call_failed(c);
    c->r->rapid_rate = v;
    return reply_ok(c);
}

static bool cmd_load_program(struct command_ctx *c)
{
    const cJSON *name = json_member_last(c->req, "programName");
    if (!cJSON_IsString(name) || name->valuestring[0] == '\0')
        return call_failed(c);
    if (c->r->interp_state == 3 || c->r->interp_state == 2)
        return reply_refused(c, "a program is running");
    snprintf(c->r->program, sizeof(c->r->program), "%s", name->valuestring);
    c->r->program_time = 0;
    return reply_ok(c);
}

static bool cmd_get_loaded_program(struct command_ctx *c)
{
    return reply_ok_text(c, "programName", c->r->program);
}

static bool cmd_play_program(struct command_ctx *c)
{
    if (c->r->program[0] == '\0')
        return reply_refused(c, "no program is loaded");
    if (!can_move(c))
        return call_failed(c);
    c->r->interp_state = 3;
    halt_arm(c->r);
    return reply_ok(c);
}

static bool cmd_pause_program(struct command_ctx *c)
{
    if (c->r->interp_state != 3)
        return reply_refused(c, "no program is running");
    c->r->interp_state = 2;
    brake_program(c->r);
    return reply_ok(c);
}

static bool cmd_resume_program(struct command_ctx *c)
{
    if (c->r->interp_state != 2)
        return reply_refused(c, "no program is paused");
    /* A move paused on a lost link goes on to its target, from rest. */
    c->r->interp_state = c->r->paused_move ? 0 : 3;
    c->r->paused_move = false;
    c->r->ramp.braking = false;
    if (c->r->ramp.halting == SIM_HALT_PAUSE)
        c->r->ramp.halting = SIM_HALT_NONE;
    return reply_ok(c);
}

/* The arm comes to rest where it is: no program, no move. */
static void stop_motion(struct sim_robot *r)
{
    bool program = r->interp_state == 3 || (r->interp_state == 2 && !r->paused_move);

    r->interp_state = 0;
    r->paused_move = false;
    if (program) {
        bool braking = r->ramp.braking;
        halt_arm(r);
        r->ramp.braking = braking;
        if (!braking)
            brake_program(r);
    } else {
        stop_arm(r);
    }
}

static bool cmd_stop_program(struct command_ctx *c)
{
    stop_motion(c->r);
    /* The manual's reply names pause_program; reproduce the quirk. */
    reply_head(c, "0", "", "pause_program");
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_get_program_state(struct command_ctx *c)
{
    static const char *const names[] = {"idle", "idle", "paused", "running"};
    return reply_ok_text(c, "programState", names[c->r->interp_state & 3]);
}

static bool cmd_set_digital_output(struct command_ctx *c)
{
    double type = -1, index = -1, value = -1;
    get_number(c->req, "type", &type);
    get_number(c->req, "index", &index);
    get_number(c->req, "value", &value);
    if ((value != 0 && value != 1) || index < 0)
        return call_failed(c);
    if (index != floor(index))
        return call_failed(c);
    if (type == 0 && index < SIM_MAX_DIO)
        c->r->dout[(int)index] = value != 0;
    else if (type == 1 && index < 8)
        c->r->tio_dout[(int)index] = value != 0;
    else if (type == 2 && index < SIM_EXTIO_DO)
        c->r->extio_do[(int)index] = value != 0;
    else
        return call_failed(c);
    return reply_ok(c);
}

static bool cmd_set_analog_output(struct command_ctx *c)
{
    double type = -1, index = -1, value;
    get_number(c->req, "type", &type);
    get_number(c->req, "index", &index);
    if (!get_number(c->req, "value", &value) || index < 0 || index != floor(index))
        return call_failed(c);
    /* The manual: type 0 the cabinet's AO, 2 the extension module's. */
    if (type == 0 && index < SIM_MAX_AIO)
        c->r->aout[(int)index] = value;
    else if (type == 2 && index < SIM_EXTIO_AO)
        c->r->extio_ao[(int)index] = value;
    else
        return call_failed(c);
    return reply_ok(c);
}

static bool cmd_get_digital_input_status(struct command_ctx *c)
{
    reply_head(c, "0", "", "get_digital_input_status");
    pyjson_key(c->w, "din_status");
    pyjson_begin_array(c->w);
    for (int i = 0; i < 136; i++)
        pyjson_int(c->w, c->r->din[i]);
    pyjson_end_array(c->w);
    pyjson_end_object(c->w);
    return true;
}

static bool set_offsets(struct command_ctx *c, const char *key,
                        double table[11][6])
{
    double v[6], id;
    if (!get_vector(c->req, key, v, 6) || !get_bounded(c->req, "id", 1, 10, &id))
        return call_failed(c);
    memcpy(table[(int)id], v, sizeof(v));
    return reply_ok(c);
}

static bool get_offsets(struct command_ctx *c, const char *key, double table[11][6])
{
    reply_head(c, "0", "", c->name);
    pyjson_key(c->w, key);
    pyjson_begin_array(c->w);
    for (int i = 0; i < 11; i++) {
        pyjson_begin_array(c->w);
        for (int k = 0; k < 6; k++)
            pyjson_float(c->w, table[i][k]);
        pyjson_end_array(c->w);
    }
    pyjson_end_array(c->w);
    pyjson_end_object(c->w);
    return true;
}

/* 4.82: the DH parameters of the simulated arm (alpha in radians, a and d
 * in mm), as the kinematics above use them. */
static bool cmd_get_dh_param(struct command_ctx *c)
{
    static const double homeoff[6] = {0, 0, 0, 0, 0, 0};
    reply_head(c, "0", "", c->name);
    pyjson_float_array(c->w, "alpha", dh_alpha, 6);
    pyjson_float_array(c->w, "a", dh_a, 6);
    pyjson_float_array(c->w, "d", dh_d, 6);
    pyjson_float_array(c->w, "joint_homeoff", homeoff, 6);
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_set_tool_offsets(struct command_ctx *c)
{
    return set_offsets(c, "tooloffset", c->r->tool_offsets);
}
static bool cmd_get_tool_offsets(struct command_ctx *c)
{
    return get_offsets(c, "tool_offsets", c->r->tool_offsets);
}
static bool cmd_set_user_offsets(struct command_ctx *c)
{
    /* The manual spells the member "userffset". */
    return set_offsets(c, "userffset", c->r->user_offsets);
}
static bool cmd_get_user_offsets(struct command_ctx *c)
{
    return get_offsets(c, "user_offsets", c->r->user_offsets);
}

static bool set_id(struct command_ctx *c, const char *key, int *out)
{
    double id;
    if (!get_bounded(c->req, key, 0, 10, &id))
        return call_failed(c);
    *out = (int)id;
    return reply_ok(c);
}

static bool cmd_set_tool_id(struct command_ctx *c)
{
    return set_id(c, "tool_id", &c->r->tool_id);
}
static bool cmd_set_user_id(struct command_ctx *c)
{
    return set_id(c, "user_frame_id", &c->r->user_id);
}

static bool cmd_torque_control_enable(struct command_ctx *c)
{
    double flag;
    if (!get_number(c->req, "enable_flag", &flag) || !c->r->enabled)
        return call_failed(c);
    c->r->drag = c->r->torque_control = flag != 0;
    return reply_ok(c);
}

static bool cmd_drag_status(struct command_ctx *c)
{
    return reply_in_order(c->w, (const char *const[]){"drag_status",
                                                      c->r->drag ? "True" : "False",
                                                      "errorCode", "0", "cmdName", c->name,
                                                      "errorMsg", "", NULL});
}

static bool cmd_protective_stop_status(struct command_ctx *c)
{
    return reply_ok_text(c, "protective_stop", c->r->protective_stop ? "1" : "0");
}

static bool cmd_emergency_stop_status(struct command_ctx *c)
{
    /* Seen on a real Zu 5s: no cmdName at all, errorCode "1". */
    return reply_in_order(c->w, (const char *const[]){"errorCode", "1", "errorMsg",
                                                      CALL_FAILED, NULL});
}

static bool cmd_wait_complete(struct command_ctx *c)
{
    /* The manual's reply has a leading space in cmdName. */
    reply_head(c, "0", "", " wait_complete");
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_set_payload(struct command_ctx *c)
{
    double mass, centroid[3];
    if (!get_number(c->req, "mass", &mass) || mass < 0 ||
        !get_vector(c->req, "centroid", centroid, 3))
        return call_failed(c);
    c->r->payload_mass = mass;
    memcpy(c->r->payload_centroid, centroid, sizeof(centroid));
    reply_head(c, "0", "", " set_payload ");
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_get_payload(struct command_ctx *c)
{
    pyjson_begin_object(c->w);
    pyjson_key(c->w, "errorCode");
    pyjson_string(c->w, "0");
    pyjson_float_array(c->w, "centroid", c->r->payload_centroid, 3);
    pyjson_key(c->w, "mass");
    pyjson_float(c->w, c->r->payload_mass);
    pyjson_key(c->w, "cmdName");
    pyjson_string(c->w, c->name);
    pyjson_key(c->w, "errorMsg");
    pyjson_string(c->w, "");
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_set_clsn_sensitivity(struct command_ctx *c)
{
    double level;
    if (!get_bounded(c->req, "sensitivityVal", 0, 5, &level))
        return call_failed(c);
    c->r->collision_level = (int)level;
    return reply_ok(c);
}

static bool cmd_get_clsn_sensitivity(struct command_ctx *c)
{
    char level[16];
    snprintf(level, sizeof(level), "%d", c->r->collision_level);
    return reply_ok_member(c, "sensitivityLevel", level);
}

static bool cmd_kine_forward(struct command_ctx *c)
{
    double q[6], pose[6];
    if (!get_vector(c->req, "jointPosition", q, 6))
        return call_failed(c);
    sim_forward_kinematics(q, pose);
    reply_head(c, "0", "", c->name);
    pyjson_float_array(c->w, "cartPosition", pose, 6);
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_kine_inverse(struct command_ctx *c)
{
    double seed[6], pose[6], q[6];
    if (!get_vector(c->req, "jointPosition", seed, 6) ||
        !get_vector(c->req, "cartPosition", pose, 6) ||
        !sim_inverse_kinematics(pose, seed, q)) {
        reply_head(c, "2", "call kine inverse failed", "kine inverse");
        pyjson_end_object(c->w);
        return true;
    }
    reply_head(c, "0", "", c->name);
    pyjson_float_array(c->w, "jointPosition", q, 6);
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_clear_error(struct command_ctx *c)
{
    c->r->protective_stop = false;
    snprintf(c->r->errcode, sizeof(c->r->errcode), "0x0");
    c->r->errmsg[0] = '\0';
    return reply_ok(c);
}

static bool cmd_get_joint_pos(struct command_ctx *c)
{
    reply_head(c, "0", "", c->name);
    pyjson_float_array(c->w, "joint_pos", c->r->joints, 6);
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_get_tcp_pos(struct command_ctx *c)
{
    reply_head(c, "0", "", " get_tcp_pos");
    pyjson_float_array(c->w, "tcp_pos", c->r->cart, 6);
    pyjson_end_object(c->w);
    return true;
}

static bool cmd_get_version(struct command_ctx *c)
{
    return reply_ok_text(c, "version", "1.5.14_13_X64 (jakasim)");
}

static bool cmd_set_network_exception_handle(struct command_ctx *c)
{
    double ms, mot;
    if (!get_bounded(c->req, "timeLimit", 0, 1e9, &ms) ||
        !get_bounded(c->req, "motType", 0, 2, &mot))
        return call_failed(c);
    c->r->net_exception_ms = (int)ms;
    c->r->net_exception_motion = (int)mot;
    c->r->net_exception_count++;
    return reply_ok(c);
}

void sim_robot_network_lost(struct sim_robot *r, enum sim_net_motion motion, char *done,
                            size_t done_size)
{
    static const char *const verbs[] = {"kept", "paused", "stopped"};
    const char *verb = verbs[motion <= SIM_NET_STOP ? motion : 0];
    bool program = r->interp_state == 3;
    bool move = r->interp_state == 0 && (r->moving || r->queued_count > 0);

    if (r->interp_state == 2) {
        snprintf(done, done_size, "the %s was paused already: left paused",
                 r->paused_move ? "move" : "program");
        return;
    }
    if (!r->enabled || (!program && !move)) {
        snprintf(done, done_size, "nothing was running");
        return;
    }
    if (program)
        snprintf(done, done_size, "%s the program %s%s", verb, r->program,
                 motion == SIM_NET_KEEP ? " running" : "");
    else
        snprintf(done, done_size, "%s the move%s", verb,
                 motion == SIM_NET_KEEP ? " running" : "");
    if (motion == SIM_NET_PAUSE) {
        if (!r->moving && r->queued_count > 0)
            start_next_move(r); /* paused as it starts */
        if (program)
            brake_program(r);
        else if (r->ramp.stop_time_s > 0)
            r->ramp.halting = SIM_HALT_PAUSE;
        else
            r->ramp.path_speed = 0;
        r->interp_state = 2;
        r->paused_move = move;
    } else if (motion == SIM_NET_STOP) {
        stop_motion(r);
    }
}

static bool cmd_quit(struct command_ctx *c)
{
    return reply_ok(c);
}

static bool cmd_shutdown(struct command_ctx *c)
{
    c->r->powered_on = c->r->enabled = false;
    return reply_ok(c);
}

static bool cmd_get_funcdi_status(struct command_ctx *c)
{
    reply_head(c, "0", "", c->name);
    pyjson_key(c->w, "funcdi_status");
    pyjson_begin_array(c->w);
    for (int i = 0; i < 12; i++) {
        pyjson_begin_array(c->w);
        pyjson_int(c->w, -1);
        pyjson_int(c->w, -1);
        pyjson_end_array(c->w);
    }
    pyjson_end_array(c->w);
    pyjson_end_object(c->w);
    return true;
}

struct command {
    const char *name;
    bool (*handle)(struct command_ctx *c);
};

static const struct command commands[] = {
    {"power_on", cmd_power_on},
    {"power_off", cmd_power_off},
    {"enable_robot", cmd_enable},
    {"disable_robot", cmd_disable},
    {"shutdown", cmd_shutdown},
    {"jog", cmd_jog},
    {"joint_move", cmd_joint_move},
    {"end_move", cmd_end_move},
    {"moveL", cmd_move_l},
    {"movc", cmd_movc},
    {"quit", cmd_quit},
    {"get_robot_state", cmd_get_robot_state},
    {"get_data", cmd_get_data},
    {"is_in_servomove", cmd_is_in_servomove},
    {"servo_move", cmd_servo_move},
    {"servo_j", cmd_servo_j},
    {"rapid_rate", cmd_rapid_rate},
    {"load_program", cmd_load_program},
    {"get_loaded_program", cmd_get_loaded_program},
    {"play_program", cmd_play_program},
    {"pause_program", cmd_pause_program},
    {"resume_program", cmd_resume_program},
    {"stop_program", cmd_stop_program},
    {"get_program_state", cmd_get_program_state},
    {"set_digital_output", cmd_set_digital_output},
    {"get_digital_input_status", cmd_get_digital_input_status},
    {"set_analog_output", cmd_set_analog_output},
    {"set_tool_offsets", cmd_set_tool_offsets},
    {"get_tool_offsets", cmd_get_tool_offsets},
    {"get_dh_param", cmd_get_dh_param},
    {"set_tool_id", cmd_set_tool_id},
    {"set_user_offsets", cmd_set_user_offsets},
    {"get_user_offsets", cmd_get_user_offsets},
    {"set_user_id", cmd_set_user_id},
    {"get_funcdi_status", cmd_get_funcdi_status},
    {"torque_control_enable", cmd_torque_control_enable},
    {"drag_status", cmd_drag_status},
    {"protective_stop_status", cmd_protective_stop_status},
    {"emergency_stop_status", cmd_emergency_stop_status},
    {"wait_complete", cmd_wait_complete},
    {"set_payload", cmd_set_payload},
    {"get_payload", cmd_get_payload},
    {"set_clsn_sensitivity", cmd_set_clsn_sensitivity},
    {"get_clsn_sensitivity", cmd_get_clsn_sensitivity},
    {"kine_forward", cmd_kine_forward},
    {"kine_inverse", cmd_kine_inverse},
    {"clear_error", cmd_clear_error},
    {"get_joint_pos", cmd_get_joint_pos},
    {"get_tcp_pos", cmd_get_tcp_pos},
    {"get_version", cmd_get_version},
    {"set_network_exception_handle", cmd_set_network_exception_handle},
    {"start_torq_sensor_payload_identify", cmd_start_payload_identify},
};

bool sim_robot_command(struct sim_robot *r, const char *json, size_t size,
                       const char *fail_cmd, struct pyjson *reply,
                       char *cmd_name, size_t cmd_name_size)
{
    cJSON *req = cJSON_ParseWithLength(json, size);
    const cJSON *name = json_member_last(req, "cmdName");
    struct command_ctx c = {r, req, NULL, reply};
    bool answered = true;

    snprintf(cmd_name, cmd_name_size, "%s",
             cJSON_IsString(name) ? name->valuestring : "?");
    if (!cJSON_IsString(name)) {
        /* What a controller answers to something it cannot call. */
        reply_in_order(reply, (const char *const[]){"errorCode", "1", "errorMsg", CALL_FAILED,
                                                    NULL});
        cJSON_Delete(req);
        return true;
    }
    c.name = name->valuestring;
    const struct command *cmd = NULL;
    for (size_t i = 0; i < sizeof(commands) / sizeof(commands[0]); i++)
        if (strcmp(commands[i].name, c.name) == 0)
            cmd = &commands[i];
    if (!cmd) {
        reply_in_order(reply, (const char *const[]){"errorCode", "1", "errorMsg", CALL_FAILED,
                                                    "cmdName", c.name, NULL});
    } else if (fail_cmd && strcmp(fail_cmd, c.name) == 0 &&
               (r->fail_times == 0 || r->failed++ < r->fail_times)) {
        if (r->fail_message)
            reply_refused(&c, r->fail_message);
        else
            call_failed(&c);
    } else {
        answered = cmd->handle(&c);
    }
    cJSON_Delete(req);
    return answered;
}
