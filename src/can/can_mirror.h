/* SPDX-License-Identifier: MIT */
/*
 * can_mirror.h - key robot status on a CAN bus, every period.
 *
 * Each period the mirror takes a snapshot of the status model and the
 * gateway's values from its owner, encodes the frames of the configured
 * groups (can_map.h) and hands them to its sink (can_sink.h), a non-blocking
 * SocketCAN socket unless a test supplies another.
 *
 * Trouble on the bus never stalls the loop and never touches Modbus:
 * - a full transmit queue (ENOBUFS, EAGAIN) drops the rest of the period;
 * - an interface that is down (ENETDOWN) is tried again every period;
 * - an interface that is absent or vanished (ENODEV, ENXIO), or any other
 *   error, closes the socket and opens it again with a backoff of
 *   CAN_MIRROR_RETRY_MIN_MS doubling up to CAN_MIRROR_RETRY_MAX_MS;
 * - a bus-off report from the controller is shown until it restarts.
 * Each is counted in the stats and logged once per change of state.
 *
 * Life cycle as libuv handles: can_mirror_init(), can_mirror_start(),
 * can_mirror_close(cb); the struct is the caller's until cb runs. The
 * snapshot callback runs from the timer and must not close the mirror.
 */
#ifndef JAKAGW_CAN_MIRROR_H
#define JAKAGW_CAN_MIRROR_H

#include <net/if.h>
#include <stdbool.h>
#include <stdint.h>
#include <uv.h>

#include "can_map.h"
#include "can_sink.h"

#define CAN_MIRROR_RETRY_MIN_MS 100
#define CAN_MIRROR_RETRY_MAX_MS 2000

struct can_mirror_config {
    char interface[IF_NAMESIZE];
    uint32_t base_id;
    bool extended_ids;
    uint32_t period_ms;
    uint32_t groups; /* bit per enum can_group */
};

/* What the mirror is doing now; the numbers are shown to Modbus clients. */
enum can_mirror_state {
    CAN_MIRROR_OFF = 0,              /* not configured, or not started */
    CAN_MIRROR_SENDING = 1,          /* the last period went out whole */
    CAN_MIRROR_QUEUE_FULL = 2,       /* the transmit queue is full */
    CAN_MIRROR_BUS_OFF = 3,          /* the controller reported bus-off */
    CAN_MIRROR_INTERFACE_DOWN = 4,   /* the interface is down */
    CAN_MIRROR_INTERFACE_ABSENT = 5, /* no such interface (yet) */
    CAN_MIRROR_FAILED = 6,           /* another error; reopening */
};

struct can_mirror_stats {
    uint64_t frames_sent;
    uint64_t frames_dropped;   /* due in a period but not sent, for any reason */
    uint64_t queue_full;       /* sends refused: transmit queue full */
    uint64_t interface_down;   /* sends or polls refused: interface down */
    uint64_t interface_absent; /* opens or sends refused: no such interface */
    uint64_t bus_off;          /* bus-off reports */
    uint64_t other_errors;     /* any other failed open, send or poll */
    uint64_t opens;            /* sockets opened */
};

struct can_mirror;

/* Fills in->status and in->gw; the mirror fills in->mirror. */
typedef void (*can_mirror_snapshot_cb)(void *user, struct can_inputs *in);

struct can_mirror {
    struct can_mirror_config cfg;
    struct can_sink *sink;
    struct can_sink socketcan; /* the default sink */
    can_mirror_snapshot_cb snapshot;
    void *user;

    enum can_mirror_state state;
    int last_error;    /* negative errno of the last failure, 0 none */
    bool sink_open;
    bool bus_off;      /* a bus-off report with no restart since */
    bool ever_sent;
    uint64_t retry_at_ms;
    uint32_t retry_delay_ms;
    uint64_t dropped_when_sending; /* frames_dropped after the last whole period */
    uint8_t rolling_counter;
    unsigned frames_per_period;
    struct can_mirror_stats stats;

    uv_loop_t *loop;
    uv_timer_t timer;
    bool started;
    uint64_t next_due_ms;
    void (*close_cb)(struct can_mirror *m);
};

/*
 * Prepares 'm' for 'cfg' with 'sink' (NULL: a SocketCAN socket). Nothing is
 * opened yet. Returns 0, or -EINVAL when the interface name is empty, the
 * period is 0, no group is on, or an identifier does not fit.
 */
int can_mirror_init(struct can_mirror *m, const struct can_mirror_config *cfg,
                    struct can_sink *sink, can_mirror_snapshot_cb snapshot, void *user);

/* Starts the period timer on 'loop'; the first period is sent at once. */
int can_mirror_start(uv_loop_t *loop, struct can_mirror *m);

/*
 * One period at 'now_ms': opens the sink if it is closed and its retry time
 * has come, reads error reports, sends every frame. The timer calls it;
 * tests call it with their own clock.
 */
void can_mirror_tick(struct can_mirror *m, uint64_t now_ms);

/* Stops the timer and closes the sink; cb runs from the loop. */
void can_mirror_close(struct can_mirror *m, void (*cb)(struct can_mirror *m));

/* Closes the sink of a mirror that was never started (tests). */
void can_mirror_release(struct can_mirror *m);

/* Resets the stats to 0 (the clear_counters coil). */
void can_mirror_clear_stats(struct can_mirror *m);

/* Failed opens, sends and polls and bus-off reports, all kinds together. */
uint64_t can_mirror_errors(const struct can_mirror_stats *stats);

/* A short name of a state, for logs and tests. */
const char *can_mirror_state_name(enum can_mirror_state state);

#endif
