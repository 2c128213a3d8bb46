/* config.c - see config.h. */
#include "config.h"

#include "log.h"

#include <errno.h>
#include <ini.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

enum key_type { KEY_STRING, KEY_UINT, KEY_UNIT_ID, KEY_WORD_ORDER, KEY_LOG_LEVEL };

struct key_info {
    const char *section;
    const char *key;
    enum key_type type;
    size_t offset;
    size_t size;    /* KEY_STRING: buffer size */
    uint32_t min, max;
    const char *default_value;
};

#define KEY(sec, name, type, member, min, max, def)                            \
    {sec, name, type, offsetof(struct gw_config, member),                      \
     sizeof(((struct gw_config *)0)->member), min, max, def}

static const struct key_info keys[] = {
    KEY("robot", "host", KEY_STRING, robot_host, 1, 0, "127.0.0.1"),
    KEY("robot", "status_port", KEY_UINT, status_port, 1, 65535, "10000"),
    KEY("robot", "command_port", KEY_UINT, command_port, 1, 65535, "10001"),
    KEY("robot", "connect_timeout_ms", KEY_UINT, connect_timeout_ms, 100, 600000, "3000"),
    KEY("robot", "reconnect_min_ms", KEY_UINT, reconnect_min_ms, 10, 600000, "200"),
    KEY("robot", "reconnect_max_ms", KEY_UINT, reconnect_max_ms, 10, 600000, "5000"),
    KEY("robot", "status_timeout_ms", KEY_UINT, status_timeout_ms, 50, 600000, "1000"),
    KEY("robot", "max_document_bytes", KEY_UINT, max_document_bytes, 65536, 16777216, "65536"),
    KEY("modbus", "bind", KEY_STRING, modbus_bind, 1, 0, "0.0.0.0"),
    KEY("modbus", "port", KEY_UINT, modbus_port, 1, 65535, "502"),
    KEY("modbus", "max_clients", KEY_UINT, max_clients, 1, 1024, "32"),
    KEY("modbus", "idle_timeout_ms", KEY_UINT, idle_timeout_ms, 0, 86400000, "60000"),
    KEY("modbus", "frame_timeout_ms", KEY_UINT, frame_timeout_ms, 50, 60000, "1000"),
    KEY("modbus", "unit_id", KEY_UNIT_ID, unit_id, 0, 255, "any"),
    KEY("modbus", "word_order", KEY_WORD_ORDER, word_order, 0, 1, "high_first"),
    KEY("log", "level", KEY_LOG_LEVEL, log_level, 0, 0, "info"),
};

static const char *const log_level_names[] = {
    [LOG_LEVEL_ERR] = "error", [LOG_LEVEL_WARNING] = "warning",
    [LOG_LEVEL_NOTICE] = "notice", [LOG_LEVEL_INFO] = "info",
    [LOG_LEVEL_DEBUG] = "debug",
};

static int parse_uint(const char *text, uint32_t min, uint32_t max, uint32_t *out,
                      char *why, size_t why_size)
{
    char *end;
    unsigned long long v;

    errno = 0;
    if (text[0] < '0' || text[0] > '9') {
        snprintf(why, why_size, "'%s' is not a whole number", text);
        return -EINVAL;
    }
    v = strtoull(text, &end, 10);
    if (errno || *end != '\0') {
        snprintf(why, why_size, "'%s' is not a whole number", text);
        return -EINVAL;
    }
    if (v < min || v > max) {
        snprintf(why, why_size, "%s is out of range %u..%u", text, min, max);
        return -EINVAL;
    }
    *out = (uint32_t)v;
    return 0;
}

static int set_key(struct gw_config *cfg, const struct key_info *k,
                   const char *value, char *why, size_t why_size)
{
    void *member = (char *)cfg + k->offset;
    uint32_t v;

    switch (k->type) {
    case KEY_STRING:
        if (value[0] == '\0' || strlen(value) >= k->size) {
            snprintf(why, why_size, "must be 1..%zu characters", k->size - 1);
            return -EINVAL;
        }
        memcpy(member, value, strlen(value) + 1);
        return 0;
    case KEY_UINT:
        if (parse_uint(value, k->min, k->max, &v, why, why_size))
            return -EINVAL;
        *(uint32_t *)member = v;
        return 0;
    case KEY_UNIT_ID:
        if (strcasecmp(value, "any") == 0) {
            *(int32_t *)member = -1;
            return 0;
        }
        if (parse_uint(value, 0, 255, &v, why, why_size)) {
            snprintf(why, why_size, "'%s' must be 'any' or 0..255", value);
            return -EINVAL;
        }
        *(int32_t *)member = (int32_t)v;
        return 0;
    case KEY_WORD_ORDER:
        if (strcasecmp(value, "high_first") == 0 || strcasecmp(value, "ABCD") == 0)
            *(uint32_t *)member = REGMAP_HIGH_WORD_FIRST;
        else if (strcasecmp(value, "low_first") == 0 || strcasecmp(value, "CDAB") == 0)
            *(uint32_t *)member = REGMAP_LOW_WORD_FIRST;
        else {
            snprintf(why, why_size, "'%s' must be high_first or low_first", value);
            return -EINVAL;
        }
        return 0;
    case KEY_LOG_LEVEL:
        for (unsigned i = 0; i < sizeof(log_level_names) / sizeof(*log_level_names); i++) {
            if (log_level_names[i] && strcasecmp(value, log_level_names[i]) == 0) {
                *(uint32_t *)member = i;
                return 0;
            }
        }
        snprintf(why, why_size, "'%s' must be error, warning, notice, info or debug",
                 value);
        return -EINVAL;
    }
    return -EINVAL;
}

void config_defaults(struct gw_config *cfg)
{
    char why[128];

    memset(cfg, 0, sizeof(*cfg));
    for (size_t i = 0; i < sizeof(keys) / sizeof(keys[0]); i++)
        set_key(cfg, &keys[i], keys[i].default_value, why, sizeof(why));
}

int config_set(struct gw_config *cfg, const char *section, const char *key,
               const char *value, char *why, size_t why_size)
{
    for (size_t i = 0; i < sizeof(keys) / sizeof(keys[0]); i++) {
        if (strcmp(keys[i].section, section) == 0 && strcmp(keys[i].key, key) == 0)
            return set_key(cfg, &keys[i], value, why, why_size);
    }
    snprintf(why, why_size, "unknown key");
    return -EINVAL;
}

struct load_state {
    struct gw_config *cfg;
    const char *path;
    char *why;
    size_t why_size;
    int line;
};

static int on_ini_entry(void *user, const char *section, const char *name,
                        const char *value)
{
    struct load_state *st = user;
    char reason[160];

    if (config_set(st->cfg, section, name, value, reason, sizeof(reason)) == 0)
        return 1;
    snprintf(st->why, st->why_size, "[%s] %s: %s", section, name, reason);
    return 0;
}

int config_load(struct gw_config *cfg, const char *path, char *why,
                size_t why_size)
{
    struct load_state st = {cfg, path, why, why_size, 0};
    char reason[384] = "";
    int rc;

    st.why = reason;
    st.why_size = sizeof(reason);
    rc = ini_parse(path, on_ini_entry, &st);
    if (rc == -1) {
        snprintf(why, why_size, "%s: cannot open: %s", path, strerror(errno));
        return -ENOENT;
    }
    if (rc != 0) {
        /* ini_parse reports the first bad line; our handler says why. */
        if (reason[0])
            snprintf(why, why_size, "%s:%d: %s", path, rc, reason);
        else
            snprintf(why, why_size, "%s:%d: not a 'key = value' or [section] line",
                     path, rc);
        return -EINVAL;
    }
    return 0;
}

int config_validate(const struct gw_config *cfg, char *why, size_t why_size)
{
    if (cfg->reconnect_min_ms > cfg->reconnect_max_ms) {
        snprintf(why, why_size,
                 "[robot] reconnect_min_ms: %u exceeds reconnect_max_ms %u",
                 cfg->reconnect_min_ms, cfg->reconnect_max_ms);
        return -EINVAL;
    }
    return 0;
}

void config_print(const struct gw_config *cfg, FILE *out)
{
    const char *section = "";

    for (size_t i = 0; i < sizeof(keys) / sizeof(keys[0]); i++) {
        const struct key_info *k = &keys[i];
        const void *m = (const char *)cfg + k->offset;
        if (strcmp(section, k->section) != 0) {
            fprintf(out, "%s[%s]\n", i ? "\n" : "", k->section);
            section = k->section;
        }
        fprintf(out, "%s = ", k->key);
        switch (k->type) {
        case KEY_STRING:
            fprintf(out, "%s\n", (const char *)m);
            break;
        case KEY_UINT:
            fprintf(out, "%u\n", *(const uint32_t *)m);
            break;
        case KEY_UNIT_ID:
            if (*(const int32_t *)m < 0)
                fprintf(out, "any\n");
            else
                fprintf(out, "%d\n", *(const int32_t *)m);
            break;
        case KEY_WORD_ORDER:
            fprintf(out, "%s\n", *(const uint32_t *)m ? "low_first" : "high_first");
            break;
        case KEY_LOG_LEVEL:
            fprintf(out, "%s\n", log_level_names[*(const uint32_t *)m]);
            break;
        }
    }
}
