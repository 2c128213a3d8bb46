/* SPDX-License-Identifier: MIT */
/*
 * gateway.h - jakagw's core: robot links -> status model -> register image
 * <- Modbus server, plus the gateway's own diagnostics.
 *
 * Life cycle as libuv handles: gateway_start(), gateway_close(cb); the
 * struct is the caller's until cb runs.
 */
#ifndef JAKAGW_GATEWAY_H
#define JAKAGW_GATEWAY_H

#include <stdbool.h>
#include <stdint.h>
#include <uv.h>

#include "audit.h"
#include "can_mirror.h"
#include "command_port.h"
#include "config.h"
#include "events.h"
#include "http_server.h"
#include "log.h"
#include "mb_rtu.h"
#include "motion.h"
#include "mb_server.h"
#include "mb_tls.h"
#include "plc_commands.h"
#include "plc_write.h"
#include "policy.h"
#include "regmap.h"
#include "robot_link.h"
#include "status.h"

/* An age never seen (no document, no heartbeat yet), as registers show it;
 * /metrics leaves such a sample out. */
#define GATEWAY_NEVER_MS 4294967295.0

struct gateway_counters {
    uint64_t documents_parsed;
    uint64_t parse_errors;
    uint64_t framing_errors;
    uint64_t oversize_documents;
    uint64_t garbage_bytes;
    uint64_t len_mismatches;
    uint64_t status_reconnects;
    uint64_t command_reconnects;
};

enum {
    GATEWAY_PART_MODBUS = 1,
    GATEWAY_PART_STATUS_LINK = 2,
    GATEWAY_PART_COMMAND_LINK = 4,
    GATEWAY_PART_CAN = 8,
    GATEWAY_PART_POLICY = 16,
    GATEWAY_PART_WRITES = 32,
    GATEWAY_PART_RTU = 64,
    GATEWAY_PART_HTTP = 128,
};

/* The policy's rows, as PLCs read its state. */
struct gateway_policy_rows {
    const struct regmap_row *fault, *fault_age_ms, *faults, *write_owner, *motion_enabled;
    const struct regmap_row *heartbeat_state; /* plc_heartbeat_state */
    const struct regmap_row *reaction, *motion_state, *motion_count;
};

struct gateway {
    uv_loop_t *loop;
    struct gw_config cfg;
    struct regmap map;
    struct regmap_image image;
    struct jaka_status *status;  /* the last good document */
    struct jaka_status *scratch; /* where the next one is parsed */
    struct jaka_status status_buffers[2];
    struct robot_link status_link;
    struct command_port command;
    struct plc_commands commands;
    struct plc_write writes; /* every Modbus write, judged before it is answered */
    struct mb_server modbus;
    struct mb_tls *mbaps; /* the Modbus/TCP Security transport, [tls] enabled */
    struct can_mirror can; /* running when [can] enabled */
    struct mb_rtu rtu;     /* running when [rtu] enabled */
    /* gateway_start failed on a setting (the serial device refuses it):
     * exit as for a bad configuration. */
    bool config_error;
    struct audit audit;    /* who commanded the robot (audit.h) */
    struct http_server http; /* running when [http] enabled (gw_http.h) */
    struct events events;    /* the status page's event log (events.h) */
    struct gateway_counters counters;
    double gw_values[GW_VALUE_COUNT];
    /* status_sequence (IR 13): counts documents, not reset by clear_counters. */
    uint16_t status_sequence;

    uint64_t started_ms;
    uint64_t last_document_ms; /* 0: none yet */
    size_t last_document_bytes;
    /* The marks of the last document seen, handled or superseded: a
     * superseded one that changes them is handled all the same. */
    struct status_marks last_marks;
    /* The status's stale streak (gateway_status_stale_ms): since when it
     * has been stale, 0 healthy; since when it has been fresh again. */
    uint64_t status_stale_since_ms;
    uint64_t status_fresh_since_ms;
    struct policy policy;
    uv_timer_t policy_timer; /* re-evaluates the policy every check period */
    struct gateway_policy_rows policy_rows;
    struct motion motion; /* the last move sent, and what the arm does */
    enum motion_state motion_logged; /* the state the log last told */
    struct log_ratelimit parse_log_limit;
    struct log_ratelimit command_log_limit;

    /* Called when a link or the freshness changes (for sd_notify STATUS=). */
    void (*on_change)(struct gateway *gw);
    unsigned parts; /* GATEWAY_PART_* started, to close */
    int closing_parts;
    void (*close_cb)(struct gateway *gw);
};

/*
 * Builds the map and the image, starts the Modbus server and both robot
 * links. Returns 0 or a negative errno, having logged what failed; call
 * gateway_close() in either case.
 */
int gateway_start(uv_loop_t *loop, struct gateway *gw, const struct gw_config *cfg);

/* Is the status data live (a document within status_timeout_ms)? */
bool gateway_status_fresh(const struct gateway *gw);

/*
 * How long the status has been stale, counting a reconnect that brings a
 * document or two as part of the same outage: from when it went stale
 * until documents have flowed with no gap for 2 x status_timeout_ms. 0
 * while healthy. Unlike status_fresh, it cannot flap.
 */
uint64_t gateway_status_stale_ms(struct gateway *gw);

/* Recomputes the gateway values (gw_values) and encodes them. */
void gateway_refresh_values(struct gateway *gw);

/* A one-line summary for sd_notify STATUS= and logs. */
void gateway_describe(const struct gateway *gw, char *buf, size_t size);

void gateway_close(struct gateway *gw, void (*cb)(struct gateway *gw));

#endif
