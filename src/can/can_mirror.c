/* SPDX-License-Identifier: MIT */
/* can_mirror.c - see can_mirror.h. */
#include "can_mirror.h"

#include "log.h"

#include <errno.h>
#include <string.h>

const char *can_mirror_state_name(enum can_mirror_state state)
{
    static const char *const names[] = {
        [CAN_MIRROR_OFF] = "off",
        [CAN_MIRROR_SENDING] = "sending",
        [CAN_MIRROR_QUEUE_FULL] = "queue full",
        [CAN_MIRROR_BUS_OFF] = "bus-off",
        [CAN_MIRROR_INTERFACE_DOWN] = "interface down",
        [CAN_MIRROR_INTERFACE_ABSENT] = "interface absent",
        [CAN_MIRROR_FAILED] = "failed",
    };
    return (unsigned)state < sizeof(names) / sizeof(names[0]) ? names[state] : "?";
}

static bool group_on(const struct can_mirror *m, const struct can_frame_def *f)
{
    return m->cfg.groups & (1u << f->group);
}

int can_mirror_init(struct can_mirror *m, const struct can_mirror_config *cfg,
                    struct can_sink *sink, can_mirror_snapshot_cb snapshot, void *user)
{
    uint32_t max_id = cfg->extended_ids ? CAN_MAX_EXT_ID : CAN_MAX_STD_ID;

    memset(m, 0, sizeof(*m));
    if (cfg->interface[0] == '\0' || cfg->period_ms == 0 ||
        (cfg->groups & CAN_GROUPS_ALL) == 0 || cfg->base_id > max_id ||
        max_id - cfg->base_id < can_map_max_offset())
        return -EINVAL;
    m->cfg = *cfg;
    can_sink_socketcan_init(&m->socketcan);
    m->sink = sink ? sink : &m->socketcan;
    m->snapshot = snapshot;
    m->user = user;
    for (unsigned i = 0; i < can_map_frame_count; i++)
        if (group_on(m, &can_map_frames[i]))
            m->frames_per_period++;
    return 0;
}

/* Logs a change of state (or of the error behind it) once. */
static void enter_state(struct can_mirror *m, enum can_mirror_state state, int err)
{
    const char *ifname = m->cfg.interface;

    /* A new error matters only where it is the whole story. */
    if (state == m->state && (state != CAN_MIRROR_FAILED || err == m->last_error))
        return;
    m->last_error = err;
    m->state = state;
    switch (state) {
    case CAN_MIRROR_SENDING:
        if (!m->ever_sent)
            log_notice("CAN mirror: sending %u frame%s every %u ms on %s (base id 0x%X%s)",
                       m->frames_per_period, m->frames_per_period == 1 ? "" : "s",
                       m->cfg.period_ms, ifname, m->cfg.base_id,
                       m->cfg.extended_ids ? ", extended" : "");
        else
            log_notice("CAN mirror: %s: sending again; %llu frames dropped meanwhile",
                       ifname,
                       (unsigned long long)(m->stats.frames_dropped - m->dropped_when_sending));
        m->ever_sent = true;
        break;
    case CAN_MIRROR_QUEUE_FULL:
        log_warn("CAN mirror: %s: transmit queue full (%s): dropping frames until it "
                 "drains", ifname, strerror(-err));
        break;
    case CAN_MIRROR_BUS_OFF:
        log_warn("CAN mirror: %s: the controller is bus-off: frames do not reach the bus "
                 "until it restarts", ifname);
        break;
    case CAN_MIRROR_INTERFACE_DOWN:
        log_warn("CAN mirror: %s: interface is down (%s): trying again every period",
                 ifname, strerror(-err));
        break;
    case CAN_MIRROR_INTERFACE_ABSENT:
        log_warn("CAN mirror: %s: no such interface (%s): opening it again, backing off "
                 "up to %u ms", ifname, strerror(-err), CAN_MIRROR_RETRY_MAX_MS);
        break;
    case CAN_MIRROR_FAILED:
        log_err("CAN mirror: %s: %s: opening it again, backing off up to %u ms", ifname,
                strerror(-err), CAN_MIRROR_RETRY_MAX_MS);
        break;
    case CAN_MIRROR_OFF:
        break;
    }
}

static void close_sink(struct can_mirror *m, uint64_t now_ms)
{
    if (m->sink_open)
        m->sink->ops->close(m->sink);
    m->sink_open = false;
    m->bus_off = false;
    if (m->retry_delay_ms == 0)
        m->retry_delay_ms = CAN_MIRROR_RETRY_MIN_MS;
    else if (m->retry_delay_ms < CAN_MIRROR_RETRY_MAX_MS / 2)
        m->retry_delay_ms *= 2;
    else
        m->retry_delay_ms = CAN_MIRROR_RETRY_MAX_MS;
    m->retry_at_ms = now_ms + m->retry_delay_ms;
}

/*
 * Counts and reports a failed open, send or poll. Returns true when the
 * sink was closed (the period is over), false when sending may go on next
 * period on the same socket.
 */
static bool handle_error(struct can_mirror *m, int err, uint64_t now_ms)
{
    switch (err) {
    case -EAGAIN:
    case -ENOBUFS:
        m->stats.queue_full++;
        enter_state(m, m->bus_off ? CAN_MIRROR_BUS_OFF : CAN_MIRROR_QUEUE_FULL, err);
        return false;
    case -ENETDOWN:
        m->stats.interface_down++;
        enter_state(m, CAN_MIRROR_INTERFACE_DOWN, err);
        return false;
    case -ENODEV:
    case -ENXIO:
        m->stats.interface_absent++;
        close_sink(m, now_ms);
        enter_state(m, CAN_MIRROR_INTERFACE_ABSENT, err);
        return true;
    default:
        m->stats.other_errors++;
        close_sink(m, now_ms);
        enter_state(m, CAN_MIRROR_FAILED, err);
        return true;
    }
}

/* Counts and reports a failed open; the next try waits for the backoff. */
static void open_failed(struct can_mirror *m, int err, uint64_t now_ms)
{
    enum can_mirror_state state;

    if (err == -ENODEV || err == -ENXIO) {
        m->stats.interface_absent++;
        state = CAN_MIRROR_INTERFACE_ABSENT;
    } else if (err == -ENETDOWN) {
        m->stats.interface_down++;
        state = CAN_MIRROR_INTERFACE_DOWN;
    } else {
        m->stats.other_errors++;
        state = CAN_MIRROR_FAILED;
    }
    close_sink(m, now_ms);
    enter_state(m, state, err);
}

static void drop(struct can_mirror *m, unsigned frames)
{
    m->stats.frames_dropped += frames;
}

/* Reads the controller's reports; returns false when the sink was closed. */
static bool poll_events(struct can_mirror *m, uint64_t now_ms)
{
    int events = m->sink->ops->poll_events(m->sink);

    if (events < 0)
        return !handle_error(m, events, now_ms);
    if (events & CAN_SINK_EVENT_BUS_OFF) {
        m->stats.bus_off++;
        m->bus_off = true;
    }
    if (events & CAN_SINK_EVENT_RESTARTED)
        m->bus_off = false;
    return true;
}

void can_mirror_tick(struct can_mirror *m, uint64_t now_ms)
{
    struct can_inputs in;
    unsigned sent = 0;
    int err = 0;

    if (!m->sink_open) {
        if (now_ms < m->retry_at_ms) {
            drop(m, m->frames_per_period);
            return;
        }
        err = m->sink->ops->open(m->sink, m->cfg.interface);
        if (err) {
            open_failed(m, err, now_ms);
            drop(m, m->frames_per_period);
            return;
        }
        m->sink_open = true;
        m->retry_delay_ms = 0;
        m->stats.opens++;
    }
    if (!poll_events(m, now_ms)) {
        drop(m, m->frames_per_period);
        return;
    }
    memset(&in, 0, sizeof(in));
    if (m->snapshot)
        m->snapshot(m->user, &in);
    in.mirror[CAN_MIRROR_rolling_counter] = m->rolling_counter++;
    in.mirror[CAN_MIRROR_frames_dropped] = (double)(m->stats.frames_dropped % 65536);
    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        uint8_t data[CAN_FRAME_MAX_DLC];
        uint32_t id = can_frame_id(f, m->cfg.base_id);

        if (!group_on(m, f))
            continue;
        can_map_encode(f, &in, data);
        err = m->sink->ops->send(m->sink, m->cfg.extended_ids ? id | CAN_SINK_EXTENDED : id,
                                 data, f->dlc);
        if (err)
            break;
        sent++;
        m->stats.frames_sent++;
    }
    if (err) {
        drop(m, m->frames_per_period - sent);
        handle_error(m, err, now_ms);
        return;
    }
    enter_state(m, m->bus_off ? CAN_MIRROR_BUS_OFF : CAN_MIRROR_SENDING, 0);
    m->dropped_when_sending = m->stats.frames_dropped;
}

/*
 * The timer is one-shot, re-armed for the next multiple of the period: the
 * frames keep their rate however long a period's work took, without drift.
 */
static void on_timer(uv_timer_t *t)
{
    struct can_mirror *m = t->data;
    uint64_t now = uv_now(m->loop);

    can_mirror_tick(m, now);
    m->next_due_ms += m->cfg.period_ms;
    if (m->next_due_ms <= now)
        m->next_due_ms = now + m->cfg.period_ms; /* late: skip, do not burst */
    uv_timer_start(&m->timer, on_timer, m->next_due_ms - now, 0);
}

int can_mirror_start(uv_loop_t *loop, struct can_mirror *m)
{
    int rc;

    if (m->started)
        return -EALREADY;
    m->loop = loop;
    rc = uv_timer_init(loop, &m->timer);
    if (rc)
        return rc;
    m->timer.data = m;
    m->started = true;
    m->next_due_ms = uv_now(loop);
    return uv_timer_start(&m->timer, on_timer, 0, 0);
}

void can_mirror_release(struct can_mirror *m)
{
    if (m->sink_open)
        m->sink->ops->close(m->sink);
    m->sink_open = false;
}

static void on_timer_closed(uv_handle_t *h)
{
    struct can_mirror *m = h->data;

    can_mirror_release(m);
    m->state = CAN_MIRROR_OFF;
    if (m->close_cb)
        m->close_cb(m);
}

void can_mirror_close(struct can_mirror *m, void (*cb)(struct can_mirror *m))
{
    m->close_cb = cb;
    if (!m->started) {
        can_mirror_release(m);
        if (cb)
            cb(m);
        return;
    }
    uv_close((uv_handle_t *)&m->timer, on_timer_closed);
}

void can_mirror_clear_stats(struct can_mirror *m)
{
    memset(&m->stats, 0, sizeof(m->stats));
    m->dropped_when_sending = 0;
}

uint64_t can_mirror_errors(const struct can_mirror_stats *stats)
{
    return stats->queue_full + stats->interface_down + stats->interface_absent +
           stats->bus_off + stats->other_errors;
}
