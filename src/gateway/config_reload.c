/* SPDX-License-Identifier: MIT */
/* config_reload.c - see config_reload.h. */
#include "config_reload.h"

#include "gw_tls.h"
#include "log.h"
#include "mb_tls.h"

#include <string.h>

/*
 * The keys that take effect on reload, and how. Each is read where it is
 * used, so a new value applies from its next use: the log level at once;
 * max_clients at the next connection; unit_id at the next request; the
 * frame and idle timeouts from each connection's next deadline (a shorter
 * idle timeout at the latest when the longer one would have expired); the
 * robot links' timeouts and backoff from the next connection attempt or
 * status document.
 */
struct live_key {
    const char *section;
    const char *key;
    void (*apply)(struct gateway *gw, const struct gw_config *next);
};

static void apply_log_level(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.log_level = next->log_level;
    log_set_level((enum log_level)next->log_level);
}

static void apply_connect_timeout(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.connect_timeout_ms = next->connect_timeout_ms;
    gw->status_link.cfg.connect_timeout_ms = next->connect_timeout_ms;
    gw->command.link.cfg.connect_timeout_ms = next->connect_timeout_ms;
}

static void apply_reconnect_min(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.reconnect_min_ms = next->reconnect_min_ms;
    gw->status_link.cfg.reconnect_min_ms = next->reconnect_min_ms;
    gw->command.link.cfg.reconnect_min_ms = next->reconnect_min_ms;
}

static void apply_reconnect_max(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.reconnect_max_ms = next->reconnect_max_ms;
    gw->status_link.cfg.reconnect_max_ms = next->reconnect_max_ms;
    gw->command.link.cfg.reconnect_max_ms = next->reconnect_max_ms;
}

static void apply_status_timeout(struct gateway *gw, const struct gw_config *next)
{
    /* The freshness the PLC reads, and the status link's silence limit. */
    gw->cfg.status_timeout_ms = next->status_timeout_ms;
    gw->status_link.cfg.silence_timeout_ms = next->status_timeout_ms;
    /* The kernel's bound follows it, from the next connection. */
    gw->status_link.cfg.user_timeout_ms = next->status_timeout_ms + 1000;
}

static void apply_link_check(struct gateway *gw, const struct gw_config *next)
{
    /* An idle period under way starts again at the new value. */
    gw->cfg.link_check_ms = next->link_check_ms;
    command_port_set_link_check(&gw->command, next->link_check_ms);
}

static void apply_max_clients(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.max_clients = next->max_clients;
    gw->modbus.cfg.max_clients = next->max_clients;
}

static void apply_idle_timeout(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.idle_timeout_ms = next->idle_timeout_ms;
    gw->modbus.cfg.idle_timeout_ms = next->idle_timeout_ms;
}

static void apply_frame_timeout(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.frame_timeout_ms = next->frame_timeout_ms;
    gw->modbus.cfg.frame_timeout_ms = next->frame_timeout_ms;
}

static void apply_unit_id(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.unit_id = next->unit_id;
    gw->modbus.cfg.unit_id = next->unit_id;
}

/*
 * [tls]: the files are read again on every reload (reload_tls), so a
 * changed name only has to be kept; new connections get what they hold.
 */
#define APPLY_TLS_TEXT(member)                                                 \
    static void apply_##member(struct gateway *gw, const struct gw_config *next) \
    {                                                                          \
        memcpy(gw->cfg.member, next->member, sizeof(gw->cfg.member));          \
    }
APPLY_TLS_TEXT(tls_certificate)
APPLY_TLS_TEXT(tls_private_key)
APPLY_TLS_TEXT(tls_client_ca)
APPLY_TLS_TEXT(tls_crl)
APPLY_TLS_TEXT(robot_tls_ca)
APPLY_TLS_TEXT(robot_tls_fingerprint)

static void apply_tls_default_rights(struct gateway *gw, const struct gw_config *next)
{
    memcpy(gw->cfg.tls_default_rights, next->tls_default_rights,
           sizeof(gw->cfg.tls_default_rights));
    gw->cfg.tls_default_rights_mask = next->tls_default_rights_mask;
}

static void apply_tls_handshake_timeout(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.tls_handshake_timeout_ms = next->tls_handshake_timeout_ms;
}

static void apply_tls_max_handshakes(struct gateway *gw, const struct gw_config *next)
{
    gw->cfg.tls_max_handshakes = next->tls_max_handshakes;
}

static const struct live_key live_keys[] = {
    {"robot", "connect_timeout_ms", apply_connect_timeout},
    {"robot", "reconnect_min_ms", apply_reconnect_min},
    {"robot", "reconnect_max_ms", apply_reconnect_max},
    {"robot", "status_timeout_ms", apply_status_timeout},
    {"robot", "link_check_ms", apply_link_check},
    {"robot", "tls_ca", apply_robot_tls_ca},
    {"robot", "tls_fingerprint", apply_robot_tls_fingerprint},
    {"modbus", "max_clients", apply_max_clients},
    {"modbus", "idle_timeout_ms", apply_idle_timeout},
    {"modbus", "frame_timeout_ms", apply_frame_timeout},
    {"modbus", "unit_id", apply_unit_id},
    {"log", "level", apply_log_level},
    {"tls", "certificate", apply_tls_certificate},
    {"tls", "private_key", apply_tls_private_key},
    {"tls", "client_ca", apply_tls_client_ca},
    {"tls", "crl", apply_tls_crl},
    {"tls", "default_rights", apply_tls_default_rights},
    {"tls", "handshake_timeout_ms", apply_tls_handshake_timeout},
    {"tls", "max_handshakes", apply_tls_max_handshakes},
};

static const struct live_key *find_live(const char *section, const char *key)
{
    for (size_t i = 0; i < sizeof(live_keys) / sizeof(live_keys[0]); i++) {
        if (strcmp(live_keys[i].section, section) == 0 && strcmp(live_keys[i].key, key) == 0)
            return &live_keys[i];
    }
    return NULL;
}

bool config_reload_is_live(const char *section, const char *key)
{
    return find_live(section, key) != NULL;
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

/*
 * The TLS files again, and [roles] (gw_tls.h): new mbaps connections get
 * the certificate, key, CA and CRL as the files are now, [roles],
 * default_rights and the handshake limits of 'next'; established
 * connections keep theirs. A file that does not load changes nothing.
 */
static void reload_tls(struct gateway *gw, const struct gw_config *next)
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

int config_reload_print_keys(FILE *out)
{
    struct gw_config defaults;
    char shown[CONFIG_TEXT_SHOWN];

    config_defaults(&defaults);
    for (size_t i = 0; i < config_key_count(); i++) {
        const char *section = config_key_section(i), *key = config_key_name(i);
        config_key_format(&defaults, i, shown, sizeof(shown));
        fprintf(out, "%s\t%s\t%s\t%s\n", section, key, shown,
                config_reload_is_live(section, key) ? "live" : "restart");
    }
    return 0;
}

unsigned config_reload_restart_keys(const struct gw_config *running,
                                    const struct gw_config *next, char *out, size_t size)
{
    static const char more[] = ", ...";
    unsigned count = 0;
    size_t used = 0;
    bool cut = false;

    if (size)
        out[0] = '\0';
    for (size_t i = 0; i < config_key_count(); i++) {
        const char *section = config_key_section(i), *key = config_key_name(i);
        char name[80];
        int n;

        if (config_key_equal(running, next, i) || find_live(section, key))
            continue;
        n = snprintf(name, sizeof(name), "%s[%s] %s", count ? ", " : "", section, key);
        count++;
        /* Room is kept for ", ..." after any name that fits. */
        if (cut || n < 0 || used + (size_t)n + sizeof(more) > size) {
            if (!cut && used + sizeof(more) <= size && count > 1)
                memcpy(out + used, more, sizeof(more));
            cut = true;
            continue;
        }
        memcpy(out + used, name, (size_t)n + 1);
        used += (size_t)n;
    }
    return count;
}

int config_reload_apply(struct gateway *gw, const struct gw_config *next,
                        struct config_reload_result *result)
{
    char was[CONFIG_TEXT_SHOWN], now[CONFIG_TEXT_SHOWN];

    memset(result, 0, sizeof(*result));
    /* Named before any live key changes gw->cfg. */
    config_reload_restart_keys(&gw->cfg, next, result->restart_keys,
                               sizeof(result->restart_keys));
    /* Key by key, through the key table, each compared as its type has it. */
    for (size_t i = 0; i < config_key_count(); i++) {
        const char *section = config_key_section(i), *key = config_key_name(i);
        const struct live_key *live;

        if (config_key_equal(&gw->cfg, next, i))
            continue;
        config_key_format(&gw->cfg, i, was, sizeof(was));
        config_key_format(next, i, now, sizeof(now));
        live = find_live(section, key);
        if (live) {
            /* Logged first: a new log level may hide the line. */
            log_notice("reload: [%s] %s: %s -> %s", section, key, was, now);
            live->apply(gw, next);
            result->applied++;
        } else {
            log_warn("reload: [%s] %s: %s needs a restart; %s stays in force until then",
                     section, key, now, was);
            result->restart++;
        }
    }
    /* The TLS files again, and [roles]: new connections get them. */
    reload_tls(gw, next);
    return 0;
}
