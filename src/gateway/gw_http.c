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

/*
 * /status.json, with and without the registers, kept between requests:
 * rebuilt when a status document came (the registers: at most every
 * STATUS_KEPT_MS), an audit record or an event was added, or the one kept
 * is STATUS_KEPT_MS old, whichever is first. Any
 * local process may fetch it back to back; built for each request it
 * cost the loop 5-7 ms (the registers) that Modbus requests waited for.
 */
#define STATUS_KEPT_MS 100

static struct status_kept {
    char *body;
    size_t size;
    uint64_t built_ms, documents, audit_seq, events_seq;
} kept[2];

static const char *status_document(struct gateway *gw, bool with_registers, size_t *size)
{
    struct status_kept *k = &kept[with_registers];
    uint64_t now = uv_now(gw->loop);

    /* The registers (about 90 KB) follow the status documents at most
     * every STATUS_KEPT_MS: at 125 documents a second, a rebuild for each
     * took an eighth of the loop from Modbus while clients fetched back
     * to back. */
    bool same_documents = with_registers || k->documents == gw->counters.documents_parsed;
    if (k->body && now - k->built_ms < STATUS_KEPT_MS && same_documents &&
        k->audit_seq == gw->audit.seq && k->events_seq == gw->events.seq) {
        *size = k->size;
        return k->body;
    }
    gateway_refresh_values(gw);
    size_t n;
    char *body = status_json_render(gw, with_registers, &n);
    if (!body)
        return NULL;
    free(k->body);
    *k = (struct status_kept){.body = body, .size = n, .built_ms = now,
                              .documents = gw->counters.documents_parsed,
                              .audit_seq = gw->audit.seq, .events_seq = gw->events.seq};
    *size = n;
    return body;
}

static void answer_new(struct gateway *gw, const struct http_request *req, bool with_registers,
                       struct http_response *resp);

static void answer(void *user, const struct http_request *req, struct http_response *resp)
{
    struct gateway *gw = user;
    const char *registers = http_request_arg(req, "registers");
    bool with_registers = registers && strcmp(registers, "1") == 0;
    /* The state cannot change within one turn of the server: what was
     * built for one request of the turn is the answer to the others.
     * /status.json is kept longer, by status_document(): not copied for
     * the turn as well. */
    const char *key = strcmp(req->path, "/metrics") == 0 ? "metrics" : NULL;

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
        const char *doc = status_document(gw, with_registers, &resp->size);
        resp->body = doc ? malloc(resp->size) : NULL;
        if (resp->body)
            memcpy(resp->body, doc, resp->size);
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
