/* SPDX-License-Identifier: MIT */
/*
 * gw_http.h - the gateway's HTTP endpoints ([http] enabled), on
 * http_server.h:
 *   /metrics      Prometheus text format (metrics.h)
 *   /status.json  the state as JSON (status_json.h); ?registers=1 adds
 *                 every register's live value
 *   /             the status page (www/status.html, built into the binary:
 *                 one self-contained page, no external assets)
 */
#ifndef JAKAGW_GW_HTTP_H
#define JAKAGW_GW_HTTP_H

#include <stddef.h>

struct gateway;

/* Starts the server when [http] enabled; 0 or a negative errno (logged). */
int gw_http_start(struct gateway *gw);

/* The page, from build/gen/status_page.c. */
extern const char status_page_html[];
extern const size_t status_page_html_size;

#endif
