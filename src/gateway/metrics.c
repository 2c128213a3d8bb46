/* SPDX-License-Identifier: MIT */
/* metrics.c - the Prometheus text format (metrics.h). */
#include "metrics.h"

#include "log.h"

#include <string.h>

#define MS 1000.0

void metrics_label_value(struct strbuf *out, const char *text)
{
    const unsigned char *p = (const unsigned char *)text;
    size_t len = strlen(text), run = 0;
    for (size_t i = 0; i <= len;) {
        const char *esc = p[i] == '\\'  ? "\\\\"
                          : p[i] == '"' ? "\\\""
                          : p[i] == '\n' ? "\\n"
                                         : NULL;
        size_t n = 1;
        /* Not UTF-8 (a PLC's JSON command name): U+FFFD for each byte, as
         * Prometheus refuses the whole scrape otherwise. */
        if (p[i] >= 0x80 && (n = utf8_sequence(p + i, len - i)) == 0) {
            esc = "\xef\xbf\xbd";
            n = 1;
        }
        if (!esc && p[i]) {
            i += n;
            continue;
        }
        strbuf_append(out, text + run, i - run);
        if (!p[i])
            break;
        strbuf_append(out, esc, strlen(esc));
        i += n;
        run = i;
    }
}

static void head(struct strbuf *out, const char *name, const char *type, const char *help)
{
    strbuf_printf(out, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

/* An age in seconds, or no sample at all when never seen: a placeholder
 * such as 4294967.295 s would wreck every graph and every comparison. */
static void age(struct strbuf *out, const char *name, const char *help, double ms)
{
    head(out, name, "gauge", help);
    if (ms < GATEWAY_NEVER_MS)
        strbuf_printf(out, "%s %.15g\n", name, ms / MS);
}

/* A metric without labels. */
static void plain(struct strbuf *out, const char *name, const char *type, const char *help,
                  double value)
{
    head(out, name, type, help);
    strbuf_printf(out, "%s %.15g\n", name, value);
}

static const char *const exception_names[16] = {
    [1] = "01", [2] = "02", [3] = "03", [4] = "04", [5] = "05", [6] = "06",
    [8] = "08", [10] = "0A", [11] = "0B",
};

static void modbus_metrics(const struct gateway *gw, struct strbuf *out)
{
    const struct mb_server_stats *st = &gw->modbus.stats;
    const struct mb_server_breakdown *by = &st->by;
    /* Each transport's row is its stats_slot. */
    const char *transports[MB_STATS_TRANSPORTS] = {0};
    transports[mb_transport_plain.stats_slot] = mb_transport_plain.name;
    transports[mb_transport_tls.stats_slot] = mb_transport_tls.name;
    transports[mb_transport_rtu.stats_slot] = mb_transport_rtu.name;

    head(out, "jakagw_modbus_requests_total", "counter",
         "Modbus requests answered, by transport and function code (their sum is input "
         "register modbus_requests).");
    for (unsigned t = 0; t < MB_STATS_TRANSPORTS; t++)
        for (unsigned fc = 0; fc < 128; fc++)
            if (by->requests[t][fc] || (t == 0 && (fc == 3 || fc == 4)))
                strbuf_printf(out,
                              "jakagw_modbus_requests_total{transport=\"%s\",function=\"%u\"} "
                              "%llu\n",
                              transports[t], fc, (unsigned long long)by->requests[t][fc]);
    head(out, "jakagw_modbus_exceptions_total", "counter",
         "Modbus exception replies, by transport and exception code (their sum is input "
         "register modbus_exceptions).");
    for (unsigned t = 0; t < MB_STATS_TRANSPORTS; t++)
        for (unsigned code = 0; code < 16; code++)
            if (by->exceptions[t][code] || (t == 0 && code == 2))
                strbuf_printf(out,
                              "jakagw_modbus_exceptions_total{transport=\"%s\",code=\"%s\"} "
                              "%llu\n",
                              transports[t],
                              exception_names[code] ? exception_names[code] : "other",
                              (unsigned long long)by->exceptions[t][code]);
    head(out, "jakagw_modbus_request_duration_seconds", "histogram",
         "Time from a request's last byte to its reply queued.");
    uint64_t cumulative = 0;
    for (unsigned b = 0; b <= MB_STATS_SERVICE_BUCKETS; b++) {
        cumulative += by->service_buckets[b];
        if (b < MB_STATS_SERVICE_BUCKETS)
            strbuf_printf(out, "jakagw_modbus_request_duration_seconds_bucket{le=\"%g\"} %llu\n",
                          mb_stats_service_bounds_s[b], (unsigned long long)cumulative);
        else
            strbuf_printf(out,
                          "jakagw_modbus_request_duration_seconds_bucket{le=\"+Inf\"} %llu\n",
                          (unsigned long long)cumulative);
    }
    strbuf_printf(out, "jakagw_modbus_request_duration_seconds_sum %.9f\n", by->service_seconds);
    strbuf_printf(out, "jakagw_modbus_request_duration_seconds_count %llu\n",
                  (unsigned long long)cumulative);
    /* Input register modbus_clients counts the RTU line while it is
     * polled (rtu_line_state 2): the line is its own transport here, not
     * a TCP client. */
    double line = gw->gw_values[GW_rtu_line_state] == MB_RTU_POLLED ? 1 : 0;
    head(out, "jakagw_modbus_clients", "gauge",
         "Modbus clients connected, by transport (their sum is input register "
         "modbus_clients).");
    strbuf_printf(out, "jakagw_modbus_clients{transport=\"%s\"} %.15g\n", transports[0],
                  gw->gw_values[GW_modbus_clients] - gw->gw_values[GW_tls_clients] - line);
    strbuf_printf(out, "jakagw_modbus_clients{transport=\"%s\"} %.15g\n", transports[1],
                  gw->gw_values[GW_tls_clients]);
    strbuf_printf(out, "jakagw_modbus_clients{transport=\"%s\"} %.15g\n", transports[2], line);
    plain(out, "jakagw_modbus_evictions_total", "counter",
          "Modbus connections closed to admit a new one at max_clients.",
          gw->gw_values[GW_modbus_evictions]);
    plain(out, "jakagw_modbus_bad_frames_total", "counter",
          "Modbus connections closed for a bad MBAP header or a reserved function code.",
          (double)st->bad_frames);
}

static void command_metrics(const struct gateway *gw, struct strbuf *out)
{
    const struct audit *a = &gw->audit;

    head(out, "jakagw_commands_total", "counter",
         "Commands sent to the robot, by command and result (done, robot error, timeout, "
         "link down, refused).");
    for (unsigned i = 0; i < a->counter_count; i++) {
        strbuf_printf(out, "jakagw_commands_total{command=\"");
        metrics_label_value(out, a->counters[i].command);
        strbuf_printf(out, "\",result=\"");
        /* "robot error" as robot_error: label values without spaces. */
        char result[sizeof(a->counters[i].result)];
        snprintf(result, sizeof(result), "%s", a->counters[i].result);
        for (char *p = result; *p; p++)
            if (*p == ' ')
                *p = '_';
        metrics_label_value(out, result);
        strbuf_printf(out, "\"} %llu\n", (unsigned long long)a->counters[i].n);
    }
    head(out, "jakagw_writes_refused_total", "counter",
         "Modbus writes the gateway refused (judged, or outside the map), by exception code.");
    for (unsigned code = 0; code < 16; code++)
        if (a->refused_writes[code] || code == 1)
            strbuf_printf(out, "jakagw_writes_refused_total{code=\"%s\"} %llu\n",
                          exception_names[code] ? exception_names[code] : "other",
                          (unsigned long long)a->refused_writes[code]);
}

/* The robot's own stops, from the last status document: a sample only for
 * a flag the controller sent (the status alert covers a stale one). */
static void robot_stop_metrics(const struct gateway *gw, struct strbuf *out)
{
    static const struct {
        const char *kind;
        enum status_field field;
    } stops[] = {{"emergency", STATUS_F_emergency_stop}, {"protective", STATUS_F_protective_stop}};

    head(out, "jakagw_robot_stop", "gauge",
         "Whether the robot is in an emergency or a protective stop (discrete inputs "
         "emergency_stop, protective_stop), as the last status document says.");
    for (size_t i = 0; i < sizeof(stops) / sizeof(stops[0]); i++) {
        const struct status_num *n = status_num_at(gw->status, stops[i].field, 0);
        if (n && n->present)
            strbuf_printf(out, "jakagw_robot_stop{kind=\"%s\"} %.0f\n", stops[i].kind,
                          n->value != 0 ? 1.0 : 0.0);
    }
}

void metrics_render(const struct gateway *gw, struct strbuf *out)
{
    const double *v = gw->gw_values;

    head(out, "jakagw_build_info", "gauge", "The gateway's version and register map.");
    strbuf_printf(out, "jakagw_build_info{version=\"%s\",map_version=\"%d\",map_crc=\"%08X\"} 1\n",
                  JAKAGW_VERSION, REGMAP_VERSION, (unsigned)v[GW_map_crc]);
    head(out, "jakagw_link_up", "gauge", "Whether a robot link is connected (1) or not (0).");
    strbuf_printf(out, "jakagw_link_up{link=\"status\"} %.0f\n", v[GW_status_link_up]);
    strbuf_printf(out, "jakagw_link_up{link=\"command\"} %.0f\n", v[GW_command_link_up]);
    plain(out, "jakagw_status_fresh", "gauge",
          "Whether the status data is live (a document within status_timeout_ms).",
          v[GW_status_fresh]);
    age(out, "jakagw_status_age_seconds",
        "Time since the last status document (no sample: none yet).", v[GW_status_age_ms]);
    plain(out, "jakagw_status_stale_seconds", "gauge",
          "How long the status has been stale, reconnects included: 0 once documents have "
          "flowed with no gap for 2 x status_timeout_ms (input register status_stale_ms).",
          v[GW_status_stale_ms] / MS);
    plain(out, "jakagw_uptime_seconds", "gauge", "Time since the gateway started.",
          v[GW_uptime_s]);
    plain(out, "jakagw_documents_parsed_total", "counter", "Status documents parsed.",
          v[GW_documents_parsed]);
    plain(out, "jakagw_parse_errors_total", "counter",
          "Status documents dropped as not valid JSON or not an object.", v[GW_parse_errors]);
    plain(out, "jakagw_framing_errors_total", "counter",
          "Status stream framing errors (garbage, oversize, truncated documents).",
          v[GW_framing_errors]);
    head(out, "jakagw_reconnects_total", "counter", "Robot link reconnections, by link.");
    strbuf_printf(out, "jakagw_reconnects_total{link=\"status\"} %.15g\n",
                  v[GW_status_reconnects]);
    strbuf_printf(out, "jakagw_reconnects_total{link=\"command\"} %.15g\n",
                  v[GW_command_reconnects]);
    modbus_metrics(gw, out);
    command_metrics(gw, out);
    plain(out, "jakagw_policy_fault", "gauge",
          "The latched network-exception fault: 0 none, 1 heartbeat lost, 2 no Modbus client, "
          "3 motion enable dropped, 4 the gateway's own loop stalled.",
          (double)gw->policy.fault);
    plain(out, "jakagw_policy_time_limit_seconds", "gauge",
          "The network-exception time limit (time_limit_ms): the PLC heartbeat's bound.",
          gw->policy.cfg.time_limit_ms / MS);
    plain(out, "jakagw_loop_stalls_total", "counter",
          "Gateway loop stalls longer than time_limit_ms (input register loop_stalls).",
          v[GW_loop_stalls]);
    plain(out, "jakagw_loop_stall_last_seconds", "gauge",
          "Length of the last loop stall (input register loop_stall_last_ms).",
          v[GW_loop_stall_last_ms] / MS);
    plain(out, "jakagw_policy_faults_total", "counter", "Network-exception faults latched.",
          (double)gw->policy.faults);
    plain(out, "jakagw_write_owner_present", "gauge",
          "Whether a Modbus client owns the write side (single_owner).",
          gw->policy.owner_address[0] ? 1 : 0);
    age(out, "jakagw_plc_heartbeat_age_seconds",
        "Time since the PLC last changed plc_heartbeat (no sample: never).",
        v[GW_plc_heartbeat_age_ms]);
    robot_stop_metrics(gw, out);
    plain(out, "jakagw_robot_handler_state", "gauge",
          "The robot's network-exception handler: 0 not sent, 1 pending, 2 accepted, 3 failed.",
          (double)gw->commands.handle_state);
    plain(out, "jakagw_can_state", "gauge", "The CAN mirror's state (input register can_state).",
          v[GW_can_state]);
    head(out, "jakagw_can_frames_total", "counter", "CAN frames of the mirror, by result.");
    strbuf_printf(out, "jakagw_can_frames_total{result=\"sent\"} %.15g\n", v[GW_can_frames_sent]);
    strbuf_printf(out, "jakagw_can_frames_total{result=\"dropped\"} %.15g\n",
                  v[GW_can_frames_dropped]);
    plain(out, "jakagw_can_errors_total", "counter", "CAN write errors.", v[GW_can_errors]);
    plain(out, "jakagw_rtu_line_state", "gauge",
          "The serial line (input register rtu_line_state): 0 off, 1 open and not polled, "
          "2 polled, 3 device absent or failed.",
          v[GW_rtu_line_state]);
    head(out, "jakagw_rtu_frames_total", "counter",
         "What the RTU line saw, by kind: good frames of every unit, CRC errors, other "
         "units' frames, broadcasts, overruns, gaps inside frames, our replies read back "
         "(echo), replies read back different (collision), frames out of turn, our last "
         "reply again within the delivery bound, answered again (repeat), exception-form "
         "frames addressed to us (exception).");
    static const struct { const char *kind; enum gw_value value; } rtu_kinds[] = {
        {"frame", GW_rtu_frames},          {"crc_error", GW_rtu_crc_errors},
        {"foreign", GW_rtu_foreign_frames}, {"broadcast", GW_rtu_broadcasts},
        {"overrun", GW_rtu_overruns},       {"gap", GW_rtu_gap_discards},
        {"echo", GW_rtu_echoes},            {"collision", GW_rtu_collisions},
        {"out_of_turn", GW_rtu_out_of_turn}, {"repeat", GW_rtu_repeats},
        {"exception", GW_rtu_exceptions},
    };
    for (size_t i = 0; i < sizeof(rtu_kinds) / sizeof(rtu_kinds[0]); i++)
        strbuf_printf(out, "jakagw_rtu_frames_total{kind=\"%s\"} %.15g\n", rtu_kinds[i].kind,
                      v[rtu_kinds[i].value]);
    plain(out, "jakagw_tls_handshakes_total", "counter",
          "Modbus/TCP Security handshakes completed.", v[GW_tls_handshakes_ok]);
    plain(out, "jakagw_tls_failures_total", "counter",
          "Modbus/TCP Security handshakes failed.", v[GW_tls_failed_total]);
    plain(out, "jakagw_http_requests_total", "counter", "HTTP requests answered.",
          (double)gw->http.requests);
    plain(out, "jakagw_http_connections_refused_total", "counter",
          "HTTP connections closed over the connection limit: the new one, or the idlest.",
          (double)gw->http.refused);
    plain(out, "jakagw_http_slow_closed_total", "counter",
          "HTTP connections closed for sending a request or reading an answer too slowly.",
          (double)gw->http.closed_slow);
}
