/* SPDX-License-Identifier: MIT */
/* motion.c - the motion tracker (motion.h). */
#include "motion.h"

#include "json_member.h"

#include <cJSON.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#define DEG (M_PI / 180.0)

const char *motion_state_name(enum motion_state state)
{
    static const char *const names[] = {"idle", "moving", "arrived", "stopped before arriving",
                                        "not arrived in time"};
    return (unsigned)state < sizeof(names) / sizeof(names[0]) ? names[state] : "unknown";
}

void motion_init(struct motion *m)
{
    memset(m, 0, sizeof(*m));
}

/* A flag of the document: 0, 1, or -1 when it did not carry it. */
static int flag_of(const struct jaka_status *s, enum status_field f)
{
    const struct status_num *n = status_num_at(s, f, 0);
    return n->present ? n->value != 0 : -1;
}

/* A whole array of six, or false. */
static bool six_of(const struct jaka_status *s, enum status_field f, double out[6])
{
    for (unsigned i = 0; i < 6; i++) {
        const struct status_num *n = status_num_at(s, f, i);
        if (!n->present)
            return false;
        out[i] = n->value;
    }
    return true;
}

void motion_view_of(const struct jaka_status *s, struct motion_view *v)
{
    const struct status_num *interp = status_num_at(s, STATUS_F_interp_state, 0);
    const struct status_num *rate = status_num_at(s, STATUS_F_rapidrate, 0);

    memset(v, 0, sizeof(*v));
    v->inpos = flag_of(s, STATUS_F_inpos);
    v->interp_state = interp->present ? (int)interp->value : -1;
    v->enabled = flag_of(s, STATUS_F_enabled);
    v->powered_on = flag_of(s, STATUS_F_powered_on);
    v->emergency_stop = flag_of(s, STATUS_F_emergency_stop);
    v->protective_stop = flag_of(s, STATUS_F_protective_stop);
    v->have_joints = six_of(s, STATUS_F_joint_actual_position, v->joints);
    v->have_tcp = six_of(s, STATUS_F_actual_position, v->tcp);
    v->rapid_rate = rate->present ? rate->value : 0;
}

static double wrap180(double a)
{
    a = fmod(a, 360.0);
    if (a > 180)
        a -= 360;
    if (a < -180)
        a += 360;
    return a;
}

/* Fixed-axis XYZ angles (deg) as a rotation matrix: Rz(c) Ry(b) Rx(a). */
static void rotation_of(const double rpy[3], double R[9])
{
    double ca = cos(rpy[0] * DEG), sa = sin(rpy[0] * DEG);
    double cb = cos(rpy[1] * DEG), sb = sin(rpy[1] * DEG);
    double cc = cos(rpy[2] * DEG), sc = sin(rpy[2] * DEG);

    R[0] = cc * cb, R[1] = cc * sb * sa - sc * ca, R[2] = cc * sb * ca + sc * sa;
    R[3] = sc * cb, R[4] = sc * sb * sa + cc * ca, R[5] = sc * sb * ca - cc * sa;
    R[6] = -sb, R[7] = cb * sa, R[8] = cb * ca;
}

double motion_orientation_error_deg(const double a[3], const double b[3])
{
    double Ra[9], Rb[9], trace = 0;

    rotation_of(a, Ra);
    rotation_of(b, Rb);
    /* trace(Ra^T Rb) = 1 + 2 cos(angle between them). */
    for (int i = 0; i < 9; i++)
        trace += Ra[i] * Rb[i];
    double c = (trace - 1) / 2;
    c = c > 1 ? 1 : c < -1 ? -1 : c;
    return acos(c) / DEG;
}

uint64_t motion_bound_ms(double travel, double speed)
{
    if (!(speed >= 1e-3))
        speed = 1e-3;
    double ms = travel / speed * 1000.0 * MOTION_BOUND_FACTOR + MOTION_BOUND_MARGIN_MS;
    /* NaN and infinities fail the comparison: capped, never converted. */
    return ms >= 0 && ms < MOTION_BOUND_MAX_MS ? (uint64_t)ms : MOTION_BOUND_MAX_MS;
}

static bool number_of(const cJSON *obj, const char *key, double *out)
{
    const cJSON *v = json_member_last(obj, key);
    if (!cJSON_IsNumber(v))
        return false;
    *out = v->valuedouble;
    return true;
}

static bool vector_of(const cJSON *obj, const char *key, double out[6])
{
    const cJSON *v = json_member_last(obj, key);
    if (!cJSON_IsArray(v) || cJSON_GetArraySize(v) < 6)
        return false;
    for (int i = 0; i < 6; i++) {
        const cJSON *e = cJSON_GetArrayItem(v, i);
        if (!cJSON_IsNumber(e))
            return false;
        out[i] = e->valuedouble;
    }
    return true;
}

/* The moves followed: their name, target member and kind. */
static const struct move_kind {
    const char *name, *member;
    enum motion_target kind;
} moves[] = {
    {"joint_move", "jointPosition", MOTION_TARGET_JOINTS},
    {"end_move", "endPosition", MOTION_TARGET_TCP},
    {"moveL", "cartPosition", MOTION_TARGET_TCP},
};

static const struct move_kind *move_named(const char *name)
{
    for (size_t i = 0; i < sizeof(moves) / sizeof(moves[0]); i++)
        if (strcmp(moves[i].name, name) == 0)
            return &moves[i];
    return NULL;
}

/* The largest change from 'from' to 'to': joints in deg, or a TCP's mm
 * and deg, whichever is the larger (moveL runs at speed in both). */
static double travel_between(enum motion_target kind, const double from[6], const double to[6])
{
    double most = 0;
    if (kind == MOTION_TARGET_JOINTS) {
        for (int i = 0; i < 6; i++)
            most = fmax(most, fabs(to[i] - from[i]));
        return most;
    }
    double mm = 0;
    for (int i = 0; i < 3; i++)
        mm += (to[i] - from[i]) * (to[i] - from[i]);
    for (int i = 3; i < 6; i++)
        most = fmax(most, fabs(wrap180(to[i] - from[i])));
    return fmax(sqrt(mm), most);
}

/* The position a new move starts from, for its travel: the target of the
 * move held before it, else what the last document shows. */
static const double *start_of(const struct motion *m, enum motion_target kind)
{
    if (m->held_count > 0) {
        const struct motion_move *before = &m->held[m->held_count - 1];
        if (before->kind == kind && before->target_known)
            return before->target;
    }
    if (!m->have_last || !(kind == MOTION_TARGET_JOINTS ? m->last.have_joints
                                                        : m->last.have_tcp))
        return NULL;
    return kind == MOTION_TARGET_JOINTS ? m->last.joints : m->last.tcp;
}

/* Where the move goes and how far: its target (relative: from where the
 * last document showed the arm), its travel for the bound. */
static void plan_move(const struct motion *m, const struct move_kind *k, const double given[6],
                      bool relative, struct motion_move *mv)
{
    bool have_arm = m->have_last && (k->kind == MOTION_TARGET_JOINTS ? m->last.have_joints
                                                                     : m->last.have_tcp);
    const double *arm = k->kind == MOTION_TARGET_JOINTS ? m->last.joints : m->last.tcp;
    const double *from = start_of(m, k->kind);

    mv->kind = k->kind;
    mv->target_known = !relative || have_arm;
    for (int i = 0; i < 6; i++)
        mv->target[i] = relative && have_arm ? arm[i] + given[i] : given[i];
    if (strcmp(k->name, "end_move") == 0)
        mv->travel = MOTION_END_MOVE_TRAVEL_DEG;
    else if (from && mv->target_known)
        mv->travel = travel_between(k->kind, from, mv->target);
    else
        mv->travel = k->kind == MOTION_TARGET_JOINTS ? MOTION_END_MOVE_TRAVEL_DEG : 1000.0;
}

/* The rapid rate the status shows now (1 when it does not). */
static double rate_now(const struct motion *m)
{
    return m->have_last && m->last.rapid_rate > 0 ? m->last.rapid_rate : 1.0;
}

static void end_moves(struct motion *m, enum motion_state state, const char *why)
{
    m->state = state;
    snprintf(m->why, sizeof(m->why), "%s", why);
    if (state != MOTION_TIMED_OUT)
        m->held_count = 0; /* a late arrival turns only 4 into 2 */
    m->stop_sent = m->stop_accepted = false;
}

/* A move of the list ended for good: the list starts again. */
static bool list_open(const struct motion *m)
{
    return m->state == MOTION_MOVING || m->state == MOTION_TIMED_OUT;
}

bool motion_sent(struct motion *m, uint64_t now_ms, const char *json, const void *tag)
{
    cJSON *doc = cJSON_Parse(json);
    const cJSON *name = json_member_last(doc, "cmdName");
    const struct move_kind *k = cJSON_IsString(name) ? move_named(name->valuestring) : NULL;
    double given[6] = {0}, speed = 0, rel = 0;

    if (!k) {
        cJSON_Delete(doc);
        return false;
    }
    bool have_target = vector_of(doc, k->member, given);
    number_of(doc, "speed", &speed);
    number_of(doc, "relFlag", &rel);
    cJSON_Delete(doc);
    if (!list_open(m) || m->state == MOTION_TIMED_OUT)
        m->held_count = 0;
    if (m->held_count == MOTION_HELD_MAX) {
        /* More than any controller holds: the oldest is long done. */
        memmove(&m->held[0], &m->held[1], (MOTION_HELD_MAX - 1) * sizeof(m->held[0]));
        m->held_count--;
    }
    struct motion_move *mv = &m->held[m->held_count];
    memset(mv, 0, sizeof(*mv));
    plan_move(m, k, given, rel != 0, mv);
    if (!have_target)
        mv->target_known = false;
    mv->tag = tag;
    mv->speed = speed;
    mv->sent_ms = now_ms;
    m->held_count++;
    snprintf(m->name, sizeof(m->name), "%s", k->name);
    m->kind = mv->kind;
    m->target_known = mv->target_known;
    memcpy(m->target, mv->target, sizeof(m->target));
    m->bound_ms = motion_bound_ms(mv->travel, mv->speed * rate_now(m));
    m->count++;
    m->state = MOTION_MOVING;
    m->stop_sent = m->stop_accepted = false;
    m->why[0] = '\0';
    return true;
}

void motion_answered(struct motion *m, uint64_t now_ms, const void *tag, uint64_t written_ms,
                     bool accepted, bool unknown)
{
    unsigned i = 0;
    while (i < m->held_count &&
           (m->held[i].tag != tag || m->held[i].reply != MOTION_REPLY_AWAITED))
        i++;
    if (i == m->held_count || !list_open(m))
        return;
    if (accepted || unknown) {
        m->held[i].reply = accepted ? MOTION_REPLY_ACCEPTED : MOTION_REPLY_LOST;
        m->held[i].answered_ms = now_ms;
        m->held[i].written_ms = written_ms != 0 && written_ms <= now_ms ? written_ms : now_ms;
        return;
    }
    /* Refused, or never sent: the robot does not hold it. */
    memmove(&m->held[i], &m->held[i + 1], (m->held_count - i - 1) * sizeof(m->held[0]));
    m->held_count--;
    if (m->held_count == 0)
        end_moves(m, MOTION_STOPPED, "refused by the robot, or not sent");
}

void motion_stop_sent(struct motion *m, uint64_t now_ms, const char *why)
{
    (void)now_ms;
    if (m->state != MOTION_MOVING)
        return;
    m->stop_sent = true;
    m->stop_accepted = false;
    snprintf(m->stop_why, sizeof(m->stop_why), "%s", why);
}

void motion_stop_answered(struct motion *m, uint64_t now_ms, bool accepted)
{
    if (m->state != MOTION_MOVING || !m->stop_sent)
        return;
    if (!accepted) {
        m->stop_sent = false; /* nothing stopped: the moves go on */
        return;
    }
    m->stop_accepted = true;
    m->stop_answered_ms = now_ms;
}

void motion_link_lost(struct motion *m, uint64_t now_ms, const char *why)
{
    (void)now_ms;
    if (m->state == MOTION_MOVING && m->held_count > 0)
        end_moves(m, MOTION_TIMED_OUT, why);
}

static bool joints_still(const struct motion_view *a, const struct motion_view *b)
{
    if (!a->have_joints || !b->have_joints)
        return false;
    for (int i = 0; i < 6; i++)
        if (fabs(a->joints[i] - b->joints[i]) > MOTION_STILL_DEG)
            return false;
    return true;
}

/* Does document 'v' show move 'mv''s target reached? */
static bool at_target(const struct motion_move *mv, const struct motion_view *v)
{
    if (!mv->target_known)
        return false;
    if (mv->kind == MOTION_TARGET_JOINTS) {
        if (!v->have_joints)
            return false;
        for (int i = 0; i < 6; i++)
            if (fabs(v->joints[i] - mv->target[i]) > MOTION_JOINT_TOL_DEG)
                return false;
        return true;
    }
    if (!v->have_tcp)
        return false;
    double mm = 0;
    for (int i = 0; i < 3; i++)
        mm += (v->tcp[i] - mv->target[i]) * (v->tcp[i] - mv->target[i]);
    return sqrt(mm) <= MOTION_TCP_TOL_MM &&
           motion_orientation_error_deg(v->tcp + 3, mv->target + 3) <= MOTION_TCP_TOL_DEG;
}

/* A stop of the robot's own that the document shows, or NULL. */
static const char *robot_stop(const struct motion_view *v)
{
    if (v->emergency_stop == 1)
        return "emergency stop";
    if (v->protective_stop == 1)
        return "protective stop";
    if (v->powered_on == 0)
        return "robot powered off";
    if (v->enabled == 0)
        return "robot disabled";
    return NULL;
}

/* The arm stands still: the document shows it unchanged since the one
 * before, and no program running. */
static bool arm_still(const struct motion *m, const struct motion_view *v)
{
    bool program = v->interp_state == 1 || v->interp_state == 3;
    return !program && m->have_previous && joints_still(&m->previous, v);
}

/* Does document 'v' (received at 'now_ms') show move 'i' reached, after
 * its reply, or after its reply was lost? The last move must also stand
 * still in position; one before it only pass its target. */
static bool shows_reached(const struct motion *m, unsigned i, uint64_t now_ms,
                          const struct motion_view *v)
{
    const struct motion_move *mv = &m->held[i];
    if (mv->reply == MOTION_REPLY_AWAITED || now_ms <= mv->answered_ms || !at_target(mv, v))
        return false;
    if (i + 1 < m->held_count)
        return true;
    return v->inpos == 1 && arm_still(m, v);
}

/* Can document 'v' (received at 'now_ms') speak of the moves held? Only
 * once the robot took the first of them: a document before its reply may
 * show a stop that a command ahead of it (clear_error, enable_robot) was
 * about to end, the arm still because the move has not begun. */
static bool after_first_reply(const struct motion *m, uint64_t now_ms)
{
    const struct motion_move *first = &m->held[0];
    return first->reply != MOTION_REPLY_AWAITED && now_ms > first->answered_ms;
}

void motion_document(struct motion *m, uint64_t now_ms, const struct motion_view *v)
{
    m->previous = m->last;
    m->have_previous = m->have_last;
    m->last = *v;
    m->have_last = true;
    m->last_document_ms = now_ms;
    if (!list_open(m) || m->held_count == 0)
        return;
    const char *stop = robot_stop(v);
    if (stop && m->state == MOTION_MOVING && after_first_reply(m, now_ms) &&
        (arm_still(m, v) || v->enabled == 0 || v->powered_on == 0)) {
        end_moves(m, MOTION_STOPPED, stop);
        return;
    }
    if (m->stop_accepted && now_ms > m->stop_answered_ms && arm_still(m, v)) {
        char why[64];
        snprintf(why, sizeof(why), "%s", m->stop_why);
        end_moves(m, MOTION_STOPPED, why);
        return;
    }
    /* In order: each move reaches its target after the one before it. */
    for (unsigned i = 0; i < m->held_count; i++) {
        struct motion_move *mv = &m->held[i];
        if (mv->reached)
            continue;
        if (!shows_reached(m, i, now_ms, v))
            return;
        mv->reached = true;
        mv->reached_ms = now_ms;
    }
    end_moves(m, MOTION_ARRIVED, "arrived");
}

/* Does the status show the arm moving? */
static bool arm_moving(const struct motion *m)
{
    return m->have_last && (m->last.inpos == 0 || !arm_still(m, &m->last));
}

bool motion_check(struct motion *m, uint64_t now_ms)
{
    if (m->state != MOTION_MOVING)
        return false;
    /* The first move not reached: from when it was written (the robot
     * starts a move on receipt, manual 4.7: a slow reply or a wait in the
     * gateway's queue gives it no more time), or the arrival of the one
     * before it if later; at the rapid rate the status shows now. */
    uint64_t from = 0;
    const struct motion_move *head = NULL;
    for (unsigned i = 0; i < m->held_count && !head; i++) {
        if (m->held[i].reached) {
            from = m->held[i].reached_ms;
            continue;
        }
        head = &m->held[i];
    }
    if (!head)
        return false;
    if (head->reply == MOTION_REPLY_AWAITED)
        return false; /* its reply's own timeout decides */
    if (head->written_ms > from)
        from = head->written_ms;
    uint64_t bound = motion_bound_ms(head->travel, head->speed * rate_now(m));
    if (now_ms < from + bound || arm_moving(m))
        return false;
    char why[64];
    snprintf(why, sizeof(why), "not arrived within %llu ms", (unsigned long long)bound);
    end_moves(m, MOTION_TIMED_OUT, why);
    return true;
}

double motion_step_deg(const struct motion *m)
{
    double step = 0;

    if (!m->have_last || !m->have_previous || !m->last.have_joints ||
        !m->previous.have_joints)
        return -1;
    for (int i = 0; i < 6; i++)
        step = fmax(step, fabs(m->last.joints[i] - m->previous.joints[i]));
    return step;
}

enum policy_robot motion_robot(const struct motion *m, bool fresh)
{
    if (!fresh || !m->have_last)
        return POLICY_ROBOT_UNKNOWN;
    const struct motion_view *v = &m->last;
    bool unchanged = m->have_previous && joints_still(&m->previous, v);
    if (v->interp_state == 1 || v->interp_state == 3)
        return POLICY_ROBOT_PROGRAM;
    /* Paused: a paused move is not in position, yet its arm holds. */
    if (v->interp_state == 2)
        return unchanged ? POLICY_ROBOT_PAUSED : POLICY_ROBOT_MOVING;
    /* In position and unchanged since the document before: still. */
    if (v->inpos != 0 && unchanged)
        return POLICY_ROBOT_STILL;
    return POLICY_ROBOT_MOVING;
}
