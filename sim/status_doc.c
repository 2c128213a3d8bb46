/* SPDX-License-Identifier: MIT */
/* status_doc.c - see status_doc.h. */
#include "status_doc.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const struct sim_profile profiles[] = {
    {"manual", 144, 66, 1, 6, 10, 4, true, false},
    {"zu5s", 135, 64, 2, 6, 11, 4, false, false},
    {"full", 199, 128, 2, 10, 11, 5, true, true},
};

const struct sim_profile *sim_profile_find(const char *name)
{
    for (size_t i = 0; i < sizeof(profiles) / sizeof(profiles[0]); i++)
        if (strcmp(profiles[i].name, name) == 0)
            return &profiles[i];
    return NULL;
}

static void bits(struct pyjson *w, const char *key, const bool *v, int n)
{
    pyjson_key(w, key);
    pyjson_begin_array(w);
    for (int i = 0; i < n; i++)
        pyjson_int(w, v[i]);
    pyjson_end_array(w);
}

/* A value for pattern slot (a, b): distinct across the document. */
static double pattern(const struct sim_robot *r, int a, int b, double normal)
{
    return r->test_pattern ? a * 100.0 + b + 0.5 : normal;
}

static void write_extio(struct pyjson *w, const struct sim_robot *r)
{
    pyjson_key(w, "extio");
    pyjson_begin_object(w);
    pyjson_key(w, "status");
    pyjson_begin_array(w);
    static const int counts[4] = {SIM_EXTIO_DI, SIM_EXTIO_DO, SIM_EXTIO_AI, SIM_EXTIO_AO};
    for (int k = 0; k < 4; k++) {
        pyjson_begin_array(w);
        for (int i = 0; i < counts[k]; i++) {
            if (k == 0)
                pyjson_int(w, r->test_pattern ? i % 3 == 0 : 0);
            else if (k == 1)
                pyjson_int(w, r->extio_do[i]); /* set_digital_output type 2 */
            else if (k == 2)
                pyjson_float(w, pattern(r, 42, i, 0.0));
            else
                pyjson_float(w, r->extio_ao[i]); /* set_analog_output type 2 */
        }
        pyjson_end_array(w);
    }
    pyjson_end_array(w);
    pyjson_key(w, "setup");
    pyjson_begin_array(w);
    pyjson_begin_array(w);
    pyjson_int(w, 1);
    pyjson_string(w, "AS228P");
    pyjson_begin_array(w);
    pyjson_string(w, "192.168.1.5");
    pyjson_int(w, 502);
    pyjson_int(w, 1);
    pyjson_end_array(w);
    pyjson_begin_array(w);
    static const int pins[4][2] = {{104096, SIM_EXTIO_DI}, {0, SIM_EXTIO_DO},
                                   {0, SIM_EXTIO_AI}, {0, SIM_EXTIO_AO}};
    for (int k = 0; k < 4; k++) {
        pyjson_begin_array(w);
        pyjson_int(w, pins[k][0] + (r->test_pattern ? k : 0));
        pyjson_int(w, pins[k][1]);
        pyjson_end_array(w);
    }
    pyjson_end_array(w);
    pyjson_string(w, "ext_0f5118ef9a5cb05b");
    pyjson_end_array(w);
    pyjson_end_array(w);
    pyjson_key(w, "num");
    pyjson_int(w, 1);
    pyjson_key(w, "pinmap");
    pyjson_begin_array(w);
    pyjson_begin_array(w);
    for (int k = 0; k < 4; k++)
        pyjson_int(w, r->test_pattern ? 10 * k + 1 : 0);
    pyjson_end_array(w);
    pyjson_end_array(w);
    pyjson_key(w, "mode");
    pyjson_int(w, 0);
    pyjson_end_object(w);
}

static void write_monitor(struct pyjson *w, const struct sim_robot *r,
                          const struct sim_profile *p)
{
    pyjson_key(w, "monitor_data");
    pyjson_begin_array(w);
    pyjson_int(w, 12338);
    pyjson_int(w, 12593);
    pyjson_float(w, pattern(r, 1, 2, 47.0));
    pyjson_float(w, pattern(r, 1, 3, r->powered_on ? 26.0 : 0.0));
    pyjson_float(w, pattern(r, 1, 4, r->powered_on ? 1.072 : 0.0));
    pyjson_begin_array(w);
    for (int j = 0; j < SIM_JOINTS; j++) {
        double moving = fabs(r->joint_vel[j]) > 0 ? 1 : 0;
        double normal[11] = {
            moving * 0.8 + (r->enabled ? 0.06 : 0), 48.0, 28.0 + j, 0.0,
            0.1 * (j + 1), 30000.0 + 1000 * j + r->uptime_s / 10,
            390097.0 + j, 0.0, floor(r->uptime_s), 0.0,
            r->enabled ? -1.0 - j : 0.0};
        pyjson_begin_array(w);
        for (int k = 0; k < p->monitor_joint; k++)
            pyjson_float(w, pattern(r, 10 + j, k, normal[k]));
        pyjson_end_array(w);
    }
    pyjson_end_array(w);
    for (int k = 6; k < p->monitor_top; k++)
        pyjson_float(w, pattern(r, 2, k, k == 9 ? 23.39 : 0.0));
    pyjson_end_array(w);
}

static void write_torqsensor(struct pyjson *w, const struct sim_robot *r,
                             const struct sim_profile *p)
{
    pyjson_key(w, "torqsensor");
    pyjson_begin_array(w);
    pyjson_begin_array(w);
    pyjson_int(w, 0);
    pyjson_begin_array(w);
    pyjson_string(w, "192.168.2.100");
    pyjson_int(w, 8080);
    pyjson_end_array(w);
    pyjson_begin_array(w);
    pyjson_float(w, pattern(r, 3, 0, 0.449));
    double centroid[3] = {pattern(r, 3, 1, 0), pattern(r, 3, 2, 0),
                          pattern(r, 3, 3, 20.0)};
    pyjson_float_array(w, NULL, centroid, 3);
    pyjson_end_array(w);
    pyjson_end_array(w);
    pyjson_begin_array(w);
    pyjson_int(w, r->test_pattern ? 1 : 0);
    pyjson_int(w, r->test_pattern ? -7 : 0);
    for (int k = 2; k < p->torq_status; k++) {
        double v[6];
        for (int i = 0; i < 6; i++)
            v[i] = pattern(r, 4 + k, i, 0.0);
        pyjson_float_array(w, NULL, v, 6);
    }
    pyjson_end_array(w);
    pyjson_end_array(w);
}

static void write_fieldbus(struct pyjson *w, const struct sim_robot *r,
                           const char *prefix, int dn, int an, int seed)
{
    static const char *const kinds[4] = {"din", "dout", "ain", "aout"};
    char key[32];

    for (int k = 0; k < 4; k++) {
        snprintf(key, sizeof(key), "%s_%s", prefix, kinds[k]);
        pyjson_key(w, key);
        pyjson_begin_array(w);
        int n = k < 2 ? dn : an;
        for (int i = 0; i < n; i++) {
            if (k < 2)
                pyjson_int(w, r->test_pattern ? (i + seed + k) % 4 == 1 : 0);
            else
                pyjson_float(w, pattern(r, seed + k, i, 0.0));
        }
        pyjson_end_array(w);
    }
}

static void write_body(struct pyjson *w, const struct sim_robot *r,
                       const struct sim_profile *p, size_t pad)
{
    pyjson_key(w, "drag_status");
    pyjson_bool(w, r->drag);
    if (p->extio)
        write_extio(w, r);
    pyjson_key(w, "errcode");
    pyjson_string(w, r->errcode);
    pyjson_key(w, "errmsg");
    if (pad) {
        char *big = malloc(pad + 1);
        if (big) {
            memset(big, 'x', pad);
            big[pad] = '\0';
            pyjson_string(w, big);
            free(big);
        } else {
            pyjson_string(w, "");
        }
    } else {
        pyjson_string(w, r->errmsg);
    }
    write_monitor(w, r, p);
    write_torqsensor(w, r, p);
    if (p->extras)
        pyjson_float_array(w, "instVel", r->joint_vel, SIM_JOINTS);
    pyjson_float_array(w, "joint_actual_position", r->joints, SIM_JOINTS);
    if (p->extras)
        pyjson_float_array(w, "joint_position", r->joint_cmd, SIM_JOINTS);
    pyjson_float_array(w, "actual_position", r->cart, 6);
    if (p->extras)
        pyjson_float_array(w, "position", r->cart, 6);
    bits(w, "din", r->din, p->dio);
    bits(w, "dout", r->dout, p->dio);
    pyjson_float_array(w, "ain", r->ain, p->aio);
    pyjson_float_array(w, "aout", r->aout, p->aio);
    if (p->extras) {
        bool keys[3] = {false, r->test_pattern, false};
        bits(w, "tio_key", keys, 3);
    }
    bits(w, "tio_din", r->tio_din, 8);
    bits(w, "tio_dout", r->tio_dout, 8);
    pyjson_float_array(w, "tio_ain", r->tio_ain, p->tio_ain);
    if (p->extras) {
        bool relay[2] = {r->test_pattern, false};
        bits(w, "relay_io", relay, 2);
        write_fieldbus(w, r, "mb_slave", 128, 64, 50);
        write_fieldbus(w, r, "pn_dev", 64, 64, 60);
        write_fieldbus(w, r, "eip_adpt", 64, 48, 70);
    }
    int task_state = !r->powered_on ? 1 : r->enabled ? 4 : 2;
    pyjson_key(w, "task_state");
    pyjson_int(w, task_state);
    pyjson_key(w, "homed");
    pyjson_begin_array(w);
    for (int i = 0; i < 9; i++)
        pyjson_int(w, i < 6);
    pyjson_end_array(w);
    pyjson_key(w, "task_mode");
    pyjson_int(w, r->drag ? 4 : r->interp_state == 3 ? 2 : 1);
    pyjson_key(w, "interp_state");
    pyjson_int(w, r->interp_state);
    pyjson_key(w, "enabled");
    pyjson_bool(w, r->enabled);
    pyjson_key(w, "paused");
    pyjson_bool(w, r->interp_state == 2);
    pyjson_key(w, "rapidrate");
    pyjson_float(w, r->rapid_rate);
    pyjson_key(w, "current_tool_id");
    pyjson_int(w, r->tool_id);
    pyjson_key(w, "current_user_id");
    pyjson_int(w, r->user_id);
    pyjson_key(w, "on_soft_limit");
    pyjson_int(w, 0);
    pyjson_key(w, "emergency_stop");
    pyjson_int(w, r->emergency_stop);
    pyjson_key(w, "drag_near_limit");
    pyjson_begin_array(w);
    for (int i = 0; i < 6; i++)
        pyjson_int(w, r->test_pattern ? i == 4 : 0);
    pyjson_end_array(w);
    pyjson_key(w, "funcdi");
    pyjson_begin_array(w);
    for (int i = 0; i < 15; i++) {
        pyjson_begin_array(w);
        pyjson_int(w, r->test_pattern ? i % 3 : -1);
        pyjson_int(w, r->test_pattern ? i + 2 : -1);
        pyjson_end_array(w);
    }
    pyjson_end_array(w);
    pyjson_key(w, "powered_on");
    pyjson_int(w, r->powered_on);
    pyjson_key(w, "inpos");
    pyjson_bool(w, !r->moving && !r->ramp.braking && r->interp_state != 3);
    pyjson_key(w, "motion_mode");
    pyjson_int(w, 1);
    pyjson_key(w, "curr_tcp_trans_vel");
    pyjson_float(w, r->tcp_speed);
    pyjson_key(w, "protective_stop");
    pyjson_int(w, r->protective_stop);
    pyjson_key(w, "point_key");
    pyjson_int(w, 0);
    if (p->extras) {
        pyjson_key(w, "motion_line");
        pyjson_int(w, r->interp_state == 3 ? 12 : 0);
        pyjson_key(w, "err_add_line");
        pyjson_int(w, r->test_pattern ? -3 : 0);
        pyjson_key(w, "tio_rs_signals");
        pyjson_begin_array(w);
        for (int i = 0; i < 8; i++) {
            char name[16];
            snprintf(name, sizeof(name), "%s", r->test_pattern && i == 1 ? "grip_force" : "");
            pyjson_begin_array(w);
            pyjson_string(w, name);
            for (int k = 1; k < 5; k++)
                pyjson_int(w, r->test_pattern ? i * 10 + k : 0);
            pyjson_float(w, pattern(r, 80 + i, 5, 0.0));
            pyjson_end_array(w);
        }
        pyjson_end_array(w);
    }
    pyjson_key(w, "netState");
    pyjson_int(w, 1);
}

size_t sim_status_document(struct pyjson *w, const struct sim_robot *r,
                           const struct sim_profile *p, size_t pad)
{
    struct pyjson body;
    char head[48];
    size_t total = 0, guess = 0;

    /* The body once, then "len" by fixed point: its digits count too. */
    pyjson_init(&body);
    pyjson_begin_object(&body);
    pyjson_key(&body, "len");
    pyjson_int(&body, 0);
    write_body(&body, r, p, pad);
    pyjson_end_object(&body);
    size_t rest = body.len - strlen("{\"len\": 0");
    for (int i = 0; i < 4; i++) {
        int n = snprintf(head, sizeof(head), "{\"len\": %zu", guess);
        total = (size_t)n + rest;
        if (total == guess)
            break;
        guess = total;
    }
    pyjson_reset(w);
    pyjson_raw(w, head);
    pyjson_raw(w, body.buf + strlen("{\"len\": 0"));
    pyjson_free(&body);
    return w->len;
}
