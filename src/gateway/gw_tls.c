/* SPDX-License-Identifier: MIT */
/* gw_tls.c - see gw_tls.h. */
#include "gw_tls.h"

#include "log.h"

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
