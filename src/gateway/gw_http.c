/* SPDX-License-Identifier: MIT */
/* gw_http.c - the gateway's HTTP endpoints (gw_http.h). */
#include "gw_http.h"

#include "gateway.h"
#include "http_server.h"
#include "metrics.h"
#include "status_json.h"
#include "strbuf.h"

#include <stdlib.h>
#include <string.h>

/*
 * The page's policy: nothing but itself. Its one inline script and style
 * are all it runs; it may fetch only from this origin; no frames, forms or
 * plugins.
 */
#define PAGE_POLICY                                                            \
    "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; " \
    "connect-src 'self'; img-src data:; base-uri 'none'; form-action 'none'; "   \
    "frame-ancestors 'none'"

static void answer_new(struct gateway *gw, const struct http_request *req, bool with_registers,
                       struct http_response *resp);

static void answer(void *user, const struct http_request *req, struct http_response *resp)
{
    struct gateway *gw = user;
    const char *registers = http_request_arg(req, "registers");
    bool with_registers = registers && strcmp(registers, "1") == 0;
    /* The state cannot change within one turn of the server: what was
     * built for one request of the turn is the answer to the others. */
    const char *key = strcmp(req->path, "/metrics") == 0       ? "metrics"
                      : strcmp(req->path, "/status.json") != 0 ? NULL
                      : with_registers                         ? "status+registers"
                                                               : "status";

    if (key && http_turn_cached(&gw->http, key, resp))
        return;
    answer_new(gw, req, with_registers, resp);
    if (key)
        http_turn_keep(&gw->http, key, resp);
}

static void answer_new(struct gateway *gw, const struct http_request *req, bool with_registers,
                       struct http_response *resp)
{
    if (strcmp(req->path, "/metrics") == 0) {
        struct strbuf b;
        gateway_refresh_values(gw);
        strbuf_init(&b, 16384);
        metrics_render(gw, &b);
        resp->body = strbuf_take(&b, &resp->size);
        resp->status = resp->body ? 200 : 0;
        resp->content_type = "text/plain; version=0.0.4; charset=utf-8";
        return;
    }
    if (strcmp(req->path, "/status.json") == 0) {
        gateway_refresh_values(gw);
        resp->body = status_json_render(gw, with_registers, &resp->size);
        resp->status = resp->body ? 200 : 0;
        resp->content_type = "application/json";
        return;
    }
    if (strcmp(req->path, "/") == 0 || strcmp(req->path, "/index.html") == 0) {
        resp->body = malloc(status_page_html_size);
        if (resp->body)
            memcpy(resp->body, status_page_html, status_page_html_size);
        resp->size = status_page_html_size;
        resp->status = resp->body ? 200 : 0;
        resp->content_type = "text/html; charset=utf-8";
        resp->security_policy = PAGE_POLICY;
        return;
    }
    static const char not_found[] = "not found: /, /status.json and /metrics are served\n";
    resp->body = strdup(not_found);
    resp->size = sizeof(not_found) - 1;
    resp->status = resp->body ? 404 : 0;
    resp->content_type = "text/plain; charset=utf-8";
}

int gw_http_start(struct gateway *gw)
{
    if (!gw->cfg.http_enabled)
        return 0;
    gw->parts |= GATEWAY_PART_HTTP;
    return http_server_start(gw->loop, &gw->http, gw->cfg.http_bind,
                             (uint16_t)gw->cfg.http_port, answer, gw);
}
