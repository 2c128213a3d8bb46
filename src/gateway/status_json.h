/* SPDX-License-Identifier: MIT */
/*
 * status_json.h - the gateway's state as one JSON document, for
 * GET /status.json and the status page.
 *
 * Members: gateway (version, uptime, wall time), links, status_age_ms,
 * robot (controller version, loaded program, errcode and errmsg), clients
 * (address, transport, certificate subject and role, write owner or not,
 * requests, exceptions, last request age), policy (heartbeat age, fault,
 * handler state, write owner), commands (the audit trail's last records,
 * oldest first), counters (every gateway value of the diagnostics
 * registers, by name); with registers = true also "registers": every
 * element of the register map with its address, name and value as the
 * image holds it now. Values are read where the diagnostics registers read
 * them (metrics.h). Every string from outside is a JSON string escaped by
 * cJSON, and '<', '>' and '&' are written as \u003c, \u003e, \u0026, so
 * the document stays inert even if a browser is tricked into reading it as
 * HTML.
 */
#ifndef JAKAGW_STATUS_JSON_H
#define JAKAGW_STATUS_JSON_H

#include <stdbool.h>
#include <stddef.h>

#include "gateway.h"

/* The document (malloc()ed, *size bytes), or NULL when out of memory. The
 * caller refreshes gw_values first. */
char *status_json_render(struct gateway *gw, bool registers, size_t *size);

#endif
