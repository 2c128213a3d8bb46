/* SPDX-License-Identifier: MIT */
/* gw_tls.c - see gw_tls.h. */
#include "gw_tls.h"

#include "gateway.h"
#include "log.h"
#include "mb_tls.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A private key without '/' names a systemd credential. */
static int key_path(const char *value, char *out, size_t size, char *why, size_t why_size)
{
    const char *dir;

    if (strchr(value, '/')) {
        snprintf(out, size, "%s", value);
        return 0;
    }
    dir = getenv("CREDENTIALS_DIRECTORY");
    if (!dir || !dir[0]) {
        snprintf(why, why_size,
                 "[tls] private_key: '%s' names a systemd credential, but there is no "
                 "$CREDENTIALS_DIRECTORY (LoadCredential= in the unit); give a path instead",
                 value);
        return -ENOENT;
    }
    snprintf(out, size, "%s/%s", dir, value);
    return 0;
}

int gw_tls_server_context(const struct gw_config *cfg, struct tls_context **out, char *why,
                          size_t why_size)
{
    char key[512];
    int rc = key_path(cfg->tls_private_key, key, sizeof(key), why, why_size);

    if (rc)
        return rc;
    struct tls_settings s = {
        .server = true,
        .certificate = cfg->tls_certificate,
        .private_key = key,
        .ca = cfg->tls_client_ca,
        .crl = cfg->tls_crl,
        .min_version = cfg->tls_min_version ? 13 : 12,
        .certificate_key = "[tls] certificate",
        .private_key_key = "[tls] private_key",
        .ca_key = "[tls] client_ca",
        .crl_key = "[tls] crl",
        .fingerprint_key = "",
    };
    return tls_context_new(&s, out, why, why_size);
}

int gw_tls_robot_context(const struct gw_config *cfg, struct tls_context **out, char *why,
                         size_t why_size)
{
    struct tls_settings s = {
        .ca = cfg->robot_tls_ca,
        .fingerprint = cfg->robot_tls_fingerprint,
        .min_version = 12,
        .certificate_key = "",
        .private_key_key = "",
        .ca_key = "[robot] tls_ca",
        .crl_key = "",
        .fingerprint_key = "[robot] tls_fingerprint",
    };
    return tls_context_new(&s, out, why, why_size);
}

int gw_tls_check(const struct gw_config *cfg, char *why, size_t why_size)
{
    struct tls_context *ctx;
    int rc;

    if (cfg->tls_enabled) {
        rc = gw_tls_server_context(cfg, &ctx, why, why_size);
        if (rc)
            return -EINVAL;
        tls_context_unref(ctx);
    }
    if (cfg->robot_tls) {
        rc = gw_tls_robot_context(cfg, &ctx, why, why_size);
        if (rc)
            return -EINVAL;
        tls_context_unref(ctx);
    }
    return 0;
}

static uint32_t rights_for_role(void *user, const char *role, bool valid, bool *listed)
{
    struct gateway *gw = user;
    return config_role_rights(&gw->cfg, role, valid, listed);
}

int gw_tls_start(struct gateway *gw)
{
    const struct gw_config *cfg = &gw->cfg;
    struct tls_context *ctx;
    char why[600];
    int rc;

    if (!cfg->tls_enabled)
        return 0;
    rc = gw_tls_server_context(cfg, &ctx, why, sizeof(why));
    if (rc) {
        log_err("mbaps: %s", why);
        return rc;
    }
    struct mb_tls_config tc = {
        .handshake_timeout_ms = cfg->tls_handshake_timeout_ms,
        .max_handshakes = cfg->tls_max_handshakes,
        .rights_for_role = rights_for_role,
        .user = gw,
    };
    gw->mbaps = calloc(1, sizeof(*gw->mbaps));
    if (!gw->mbaps) {
        tls_context_unref(ctx);
        return -ENOMEM;
    }
    rc = mb_tls_init(gw->mbaps, ctx, &tc);
    if (rc) {
        tls_context_unref(ctx);
        return rc;
    }
    log_notice("mbaps: certificate \"%s\"; TLS %s and later; clients must chain to %s%s%s",
               tls_context_subject(ctx), cfg->tls_min_version ? "1.3" : "1.2",
               cfg->tls_client_ca, cfg->tls_crl[0] ? ", CRL " : "", cfg->tls_crl);
    return mb_server_listen(&gw->modbus, cfg->tls_bind[0] ? cfg->tls_bind : cfg->modbus_bind,
                            (uint16_t)cfg->tls_port, cfg->tls_listen_fd, &mb_transport_tls,
                            gw->mbaps);
}

int gw_tls_robot_links(const struct gw_config *cfg, struct tls_context **ctx, const char *what)
{
    char why[600];

    *ctx = NULL;
    if (!cfg->robot_tls)
        return 0;
    if (gw_tls_robot_context(cfg, ctx, why, sizeof(why)) != 0) {
        log_err("%s: %s", what, why);
        return -EINVAL;
    }
    log_notice("%s: TLS, the controller verified with %s%s%s", what,
               cfg->robot_tls_ca[0] ? cfg->robot_tls_ca : "",
               cfg->robot_tls_ca[0] && cfg->robot_tls_fingerprint[0] ? " and " : "",
               cfg->robot_tls_fingerprint[0] ? "the pinned SHA-256 fingerprint" : "");
    return 0;
}

/*
 * [robot] tls (its own value needs a restart): tls_ca and tls_fingerprint,
 * already applied to gw->cfg, and the CA file as it is now, for the robot
 * links' next connections; a file that does not load changes nothing.
 */
static void reload_robot_context(struct gateway *gw)
{
    struct tls_context *ctx;

    if (!(gw->parts & GATEWAY_PART_COMMAND_LINK) ||
        gw_tls_robot_links(&gw->cfg, &ctx, "reload: robot links (next connections)") != 0 ||
        !ctx)
        return;
    robot_link_set_tls(&gw->status_link, ctx);
    robot_link_set_tls(&gw->command.link, ctx);
    tls_context_unref(ctx);
}

void gw_tls_reload(struct gateway *gw, const struct gw_config *next)
{
    struct gw_config *cfg = &gw->cfg;
    struct tls_context *ctx;
    char why[600];
    bool roles_changed = cfg->role_count != next->role_count ||
                         memcmp(cfg->roles, next->roles, sizeof(cfg->roles)) != 0;

    if (roles_changed) {
        memcpy(cfg->roles, next->roles, sizeof(cfg->roles));
        cfg->role_count = next->role_count;
        log_notice("reload: [roles]: %u roles; new mbaps connections get them",
                   cfg->role_count);
    }
    reload_robot_context(gw);
    if (!gw->mbaps)
        return; /* [tls] enabled needs a restart: config_reload.c says so */
    /* The files are read again even when no key changed: rotating a
     * certificate is replacing the file and reloading. */
    if (gw_tls_server_context(next, &ctx, why, sizeof(why)) != 0) {
        log_err("reload: mbaps: %s; new connections keep the certificate, key, CA and CRL "
                "in force",
                why);
        return;
    }
    mb_tls_set_context(gw->mbaps, ctx);
    gw->mbaps->cfg.handshake_timeout_ms = next->tls_handshake_timeout_ms;
    gw->mbaps->cfg.max_handshakes = next->tls_max_handshakes;
    log_notice("reload: mbaps: new connections get certificate \"%s\" and the CA and CRL as "
               "the files are now; established ones keep theirs",
               tls_context_subject(ctx));
}

void gw_tls_refresh_values(struct gateway *gw, double *v)
{
    static const struct mb_tls_stats none;
    const struct mb_tls_stats *s = gw->mbaps ? &gw->mbaps->stats : &none;

    v[GW_tls_clients] = s->clients;
    v[GW_tls_handshakes_running] = s->handshakes;
    v[GW_tls_handshakes_ok] = (double)s->handshakes_ok;
    v[GW_tls_failed_total] = (double)mb_tls_failed_total(s);
    v[GW_tls_failed_no_certificate] = (double)s->failed[TLS_FAIL_NO_CERTIFICATE];
    v[GW_tls_failed_untrusted] = (double)s->failed[TLS_FAIL_UNTRUSTED];
    v[GW_tls_failed_expired] = (double)s->failed[TLS_FAIL_EXPIRED];
    v[GW_tls_failed_revoked] = (double)s->failed[TLS_FAIL_REVOKED];
    v[GW_tls_failed_protocol] = (double)s->failed[TLS_FAIL_PROTOCOL];
    v[GW_tls_failed_timeout] = (double)s->failed[TLS_FAIL_TIMEOUT];
    v[GW_tls_failed_over_limit] = (double)s->failed[TLS_FAIL_OVER_LIMIT];
    v[GW_status_link_tls_failure] = gw->status_link.tls_failure;
    v[GW_command_link_tls_failure] = gw->command.link.tls_failure;
}

void gw_tls_clear_counters(struct gateway *gw)
{
    if (!gw->mbaps)
        return;
    gw->mbaps->stats.handshakes_ok = 0;
    memset(gw->mbaps->stats.failed, 0, sizeof(gw->mbaps->stats.failed));
}
