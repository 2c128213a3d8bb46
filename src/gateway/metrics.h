/* SPDX-License-Identifier: MIT */
/*
 * metrics.h - the gateway's state in the Prometheus text format (0.0.4),
 * for GET /metrics.
 *
 * One source of truth: every value is read where the diagnostics registers
 * read it (gateway_refresh_values, gw_values, the server's and the CAN
 * mirror's statistics, the policy, the audit trail's command counters), at
 * the moment of the scrape; nothing here counts anything. Counters that
 * "clear counters" (coil 0) resets start again from 0, which Prometheus
 * takes as a counter reset. Names follow Prometheus' conventions: base
 * units (seconds), _total for counters; the names the issue fixed are
 * jakagw_link_up{link}, jakagw_status_age_seconds,
 * jakagw_modbus_requests_total, jakagw_commands_total{command,result} and
 * jakagw_policy_fault.
 */
#ifndef JAKAGW_METRICS_H
#define JAKAGW_METRICS_H

#include "gateway.h"
#include "strbuf.h"

/* Appends every metric; the caller refreshes gw_values first. */
void metrics_render(const struct gateway *gw, struct strbuf *out);

/* Appends 'text' escaped as a Prometheus label value (\\, \", \n). */
void metrics_label_value(struct strbuf *out, const char *text);

#endif
