/* SPDX-License-Identifier: MIT */
/* config.c - see config.h. */
#include "config.h"

#include "can_map.h"
#include "ip_allow.h"
#include "log.h"
#include "tls.h"

#include <ctype.h>
#include <errno.h>
#include <ini.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <uv.h>


/*
 * KEY_HOST: an IP address or a host name, resolved when connecting.
 * KEY_IP_ADDRESS: a literal IPv4 or IPv6 address, checked with the same
 * uv_ip4_addr/uv_ip6_addr calls that the Modbus server binds with, so
 * --check-config refuses what the daemon would refuse at start.
 */
enum key_type {
    KEY_STRING,
    KEY_HOST,
    KEY_IP_ADDRESS,
    KEY_UINT,
    KEY_UNIT_ID,
    KEY_WORD_ORDER,
    KEY_CHOICE, /* one of key_info.choices, stored as its index (uint32_t) */
    KEY_LOG_LEVEL,
    KEY_BOOL,
    KEY_INTERFACE, /* a network interface name, or "" for none */
    KEY_CAN_ID,    /* decimal or 0x hex, up to 'max' */
    KEY_CAN_GROUPS, /* a frame group list (can_map_parse_groups) */
    KEY_IP_LIST,    /* write_allow: literal addresses, parsed once here into
                       write_allow_addrs (ip_allow.h) */
    KEY_PATH,       /* a file name, loaded where it is used (gw_tls.h) */
    KEY_RIGHTS,     /* [tls] default_rights, [rtu] rights: read, write or
                       write classes, parsed into the mask rights_mask() names */
    KEY_FINGERPRINT /* a SHA-256 fingerprint, or "" */
};

struct key_info {
    const char *section;
    const char *key;
    enum key_type type;
    size_t offset;
    size_t size;    /* KEY_STRING: buffer size */
    uint32_t min, max;
    const char *default_value;
    const char *const *choices; /* KEY_CHOICE: NULL-terminated */
};

#define KEY(sec, name, type, member, min, max, def)                            \
    {sec, name, type, offsetof(struct gw_config, member),                      \
     sizeof(((struct gw_config *)0)->member), min, max, def, NULL}
#define KEY_C(sec, name, member, choices, def)                                 \
    {sec, name, KEY_CHOICE, offsetof(struct gw_config, member),                \
     sizeof(((struct gw_config *)0)->member), 0, 0, def, choices}

/* [network_exception] action and the robot's motType: the same three. */
static const char *const action_names[] = {"keep", "pause", "stop", NULL};
/* [network_exception] watch: index + 1 is enum policy_watch. */
static const char *const watch_names[] = {"heartbeat", "connection", "both", NULL};
/* [network_exception] owner: index 1 is owner_by_connection. */
static const char *const owner_names[] = {"host", "connection", NULL};
/* [tls] min_version. */
static const char *const tls_version_names[] = {"1.2", "1.3", NULL};
/* [rtu] parity: the index is enum mb_rtu_parity. */
static const char *const parity_names[] = {"none", "even", "odd", NULL};

static const struct key_info keys[] = {
    KEY("robot", "host", KEY_HOST, robot_host, 1, 0, "127.0.0.1"),
    KEY("robot", "status_port", KEY_UINT, status_port, 1, 65535, "10000"),
    KEY("robot", "command_port", KEY_UINT, command_port, 1, 65535, "10001"),
    KEY("robot", "connect_timeout_ms", KEY_UINT, connect_timeout_ms, 100, 600000, "3000"),
    KEY("robot", "reconnect_min_ms", KEY_UINT, reconnect_min_ms, 10, 600000, "200"),
    KEY("robot", "reconnect_max_ms", KEY_UINT, reconnect_max_ms, 10, 600000, "5000"),
    KEY("robot", "status_timeout_ms", KEY_UINT, status_timeout_ms, 50, 600000, "1000"),
    KEY("robot", "link_check_ms", KEY_UINT, link_check_ms, 100, 60000, "1000"),
    /*
     * The framer buffers a whole document and cJSON parses it on the loop
     * thread: a real document is about 9 KB, a 256 KiB one parses in a few
     * milliseconds, while a 14 MB one stalled the loop (Modbus answers, the
     * systemd watchdog) for 1.2-1.6 s.
     */
    KEY("robot", "max_document_bytes", KEY_UINT, max_document_bytes, 65536, 262144, "65536"),
    KEY("robot", "tls", KEY_BOOL, robot_tls, 0, 1, "false"),
    KEY("robot", "tls_ca", KEY_PATH, robot_tls_ca, 0, 0, ""),
    KEY("robot", "tls_fingerprint", KEY_FINGERPRINT, robot_tls_fingerprint, 0, 0, ""),
    KEY("modbus", "enabled", KEY_BOOL, modbus_enabled, 0, 1, "true"),
    KEY("modbus", "bind", KEY_IP_ADDRESS, modbus_bind, 1, 0, "0.0.0.0"),
    KEY("modbus", "port", KEY_UINT, modbus_port, 1, 65535, "502"),
    KEY("modbus", "max_clients", KEY_UINT, max_clients, 1, 1024, "32"),
    KEY("modbus", "idle_timeout_ms", KEY_UINT, idle_timeout_ms, 0, 86400000, "60000"),
    KEY("modbus", "frame_timeout_ms", KEY_UINT, frame_timeout_ms, 50, 60000, "1000"),
    KEY("modbus", "unit_id", KEY_UNIT_ID, unit_id, 0, 255, "any"),
    KEY("modbus", "word_order", KEY_WORD_ORDER, word_order, 0, 1, "high_first"),
    KEY("modbus", "read_only", KEY_BOOL, read_only, 0, 1, "false"),
    KEY("modbus", "write_allow", KEY_IP_LIST, write_allow, 0, 0, ""),
    KEY("commands", "motion", KEY_BOOL, motion, 0, 1, "false"),
    KEY("commands", "allow_shutdown", KEY_BOOL, allow_shutdown, 0, 1, "false"),
    KEY("commands", "reply_timeout_ms", KEY_UINT, reply_timeout_ms, 100, 60000, "2000"),
    KEY("network_exception", "time_limit_ms", KEY_UINT, ne_time_limit_ms, 100, 600000, "1000"),
    KEY_C("network_exception", "action", ne_action, action_names, "pause"),
    KEY_C("network_exception", "watch", ne_watch, watch_names, "heartbeat"),
    KEY("network_exception", "motion_enable", KEY_BOOL, ne_motion_enable, 0, 1, "false"),
    KEY("network_exception", "single_owner", KEY_BOOL, ne_single_owner, 0, 1, "true"),
    KEY_C("network_exception", "owner", ne_owner, owner_names, "connection"),
    KEY("network_exception", "stop_time_ms", KEY_UINT, ne_stop_time_ms, 0, 60000, "1500"),
    KEY("network_exception", "require_heartbeat", KEY_BOOL, ne_require_heartbeat, 0, 1, "true"),
    KEY("network_exception", "robot_time_limit_ms", KEY_UINT, ne_robot_time_limit_ms, 0, 600000, "1000"),
    KEY_C("network_exception", "robot_action", ne_robot_action, action_names, "pause"),
    KEY("network_exception", "require_robot_handle", KEY_BOOL, ne_require_robot_handle, 0, 1, "true"),
    KEY("log", "level", KEY_LOG_LEVEL, log_level, 0, 0, "info"),
    KEY("can", "enabled", KEY_BOOL, can_enabled, 0, 1, "false"),
    KEY("can", "interface", KEY_INTERFACE, can_interface, 0, 0, ""),
    KEY("can", "base_id", KEY_CAN_ID, can_base_id, 0, CAN_MAX_EXT_ID, "0x500"),
    KEY("can", "extended_ids", KEY_BOOL, can_extended_ids, 0, 1, "false"),
    KEY("can", "period_ms", KEY_UINT, can_period_ms, 5, 10000, "100"),
    KEY("can", "frames", KEY_CAN_GROUPS, can_groups, 0, 0, "all"),
    KEY("tls", "enabled", KEY_BOOL, tls_enabled, 0, 1, "false"),
    KEY("tls", "bind", KEY_IP_ADDRESS, tls_bind, 0, 0, ""),
    KEY("tls", "port", KEY_UINT, tls_port, 1, 65535, "802"),
    KEY("tls", "certificate", KEY_PATH, tls_certificate, 0, 0, ""),
    KEY("tls", "private_key", KEY_PATH, tls_private_key, 0, 0, ""),
    KEY("tls", "client_ca", KEY_PATH, tls_client_ca, 0, 0, ""),
    KEY("tls", "crl", KEY_PATH, tls_crl, 0, 0, ""),
    KEY_C("tls", "min_version", tls_min_version, tls_version_names, "1.2"),
    KEY("tls", "handshake_timeout_ms", KEY_UINT, tls_handshake_timeout_ms, 100, 60000, "3000"),
    KEY("tls", "max_handshakes", KEY_UINT, tls_max_handshakes, 1, 1024, "16"),
    KEY("tls", "default_rights", KEY_RIGHTS, tls_default_rights, 0, 0, "read"),
    KEY("rtu", "enabled", KEY_BOOL, rtu_enabled, 0, 1, "false"),
    KEY("rtu", "device", KEY_PATH, rtu_device, 0, 0, ""),
    KEY("rtu", "baud", KEY_UINT, rtu_baud, 1200, 921600, "19200"),
    KEY_C("rtu", "parity", rtu_parity, parity_names, "even"),
    KEY("rtu", "stop_bits", KEY_UINT, rtu_stop_bits, 1, 2, "1"),
    KEY("rtu", "unit_id", KEY_UINT, rtu_unit_id, 1, 247, "1"),
    KEY("rtu", "rs485", KEY_BOOL, rtu_rs485, 0, 1, "false"),
    KEY("rtu", "local_echo", KEY_BOOL, rtu_local_echo, 0, 1, "false"),
    KEY("rtu", "delivery_ms", KEY_UINT, rtu_delivery_ms, 0, 255, "16"),
    KEY("rtu", "rights", KEY_RIGHTS, rtu_rights, 0, 0, "read"),
    KEY("http", "enabled", KEY_BOOL, http_enabled, 0, 1, "false"),
    KEY("http", "bind", KEY_IP_ADDRESS, http_bind, 1, 0, "127.0.0.1"),
    KEY("http", "port", KEY_UINT, http_port, 1, 65535, "10502"),
};

#define N_KEYS (sizeof(keys) / sizeof(keys[0]))

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

static bool is_ip_address(const char *text)
{
    struct sockaddr_in a4;
    struct sockaddr_in6 a6;

    return uv_ip4_addr(text, 0, &a4) == 0 || uv_ip6_addr(text, 0, &a6) == 0;
}

/*
 * A host name as RFC 1123 has it (letters, digits, '-' inside labels of 1..63
 * characters, 253 at most), with '_' tolerated as resolvers do. Digits and
 * dots alone must make an IPv4 address: getaddrinfo would otherwise send
 * "999.1.1.1" to DNS and the link would retry it forever.
 */
static bool is_host_name(const char *text)
{
    size_t len = strlen(text), label = 0;

    if (len > 253 || strspn(text, "0123456789.") == len)
        return false;
    for (const char *p = text; *p; p++) {
        if (*p == '.') {
            if (label == 0 || p[-1] == '-')
                return false;
            label = 0;
            continue;
        }
        if (!isalnum((unsigned char)*p) && *p != '-' && *p != '_')
            return false;
        if ((label == 0 && *p == '-') || ++label > 63)
            return false;
    }
    return len > 0 && text[len - 1] != '-';
}

static int parse_bool(const char *text, bool *out, char *why, size_t why_size)
{
    static const char *const yes[] = {"true", "yes", "on", "1"};
    static const char *const no[] = {"false", "no", "off", "0"};

    for (size_t i = 0; i < sizeof(yes) / sizeof(yes[0]); i++) {
        if (strcasecmp(text, yes[i]) == 0 || strcasecmp(text, no[i]) == 0) {
            *out = strcasecmp(text, yes[i]) == 0;
            return 0;
        }
    }
    snprintf(why, why_size, "'%s' must be true or false", text);
    return -EINVAL;
}

/* As the kernel accepts them: shorter than IF_NAMESIZE, no '/', ':' or space. */
static int parse_interface(const char *text, char *out, size_t size, char *why,
                           size_t why_size)
{
    if (strlen(text) >= size) {
        snprintf(why, why_size, "must be at most %zu characters", size - 1);
        return -EINVAL;
    }
    for (const char *p = text; *p; p++) {
        if (*p == '/' || *p == ':' || !isgraph((unsigned char)*p)) {
            snprintf(why, why_size, "'%s' is not a network interface name", text);
            return -EINVAL;
        }
    }
    if (strcmp(text, ".") == 0 || strcmp(text, "..") == 0) {
        snprintf(why, why_size, "'%s' is not a network interface name", text);
        return -EINVAL;
    }
    memcpy(out, text, strlen(text) + 1);
    return 0;
}

static int parse_can_id(const char *text, uint32_t max, uint32_t *out, char *why,
                        size_t why_size)
{
    bool hex = text[0] == '0' && (text[1] == 'x' || text[1] == 'X');
    const char *digits = hex ? text + 2 : text;
    unsigned long long v;
    char *end;

    errno = 0;
    v = strtoull(digits, &end, hex ? 16 : 10);
    if (!isxdigit((unsigned char)digits[0]) || errno || *end != '\0') {
        snprintf(why, why_size, "'%s' is not a CAN identifier (decimal or 0x hex)", text);
        return -EINVAL;
    }
    if (v > max) {
        snprintf(why, why_size, "%s is out of range 0..0x%X", text, max);
        return -EINVAL;
    }
    *out = (uint32_t)v;
    return 0;
}

/* Where a KEY_RIGHTS key keeps its parsed rights. */
static size_t rights_mask_offset(const struct key_info *k)
{
    if (k->offset == offsetof(struct gw_config, rtu_rights))
        return offsetof(struct gw_config, rtu_rights_mask);
    return offsetof(struct gw_config, tls_default_rights_mask);
}

static uint32_t *rights_mask(struct gw_config *cfg, const struct key_info *k)
{
    return (uint32_t *)((char *)cfg + rights_mask_offset(k));
}

static int set_key(struct gw_config *cfg, const struct key_info *k,
                   const char *value, char *why, size_t why_size)
{
    void *member = (char *)cfg + k->offset;
    uint32_t v;

    switch (k->type) {
    case KEY_IP_LIST: {
        struct ip_allow parsed;
        char reason[96];
        if (strlen(value) >= k->size) {
            snprintf(why, why_size, "must be at most %zu characters", k->size - 1);
            return -EINVAL;
        }
        if (strcmp(value, CONFIG_WRITE_ALLOW_NONE) == 0) {
            /* No address: no plain Modbus TCP client may write. */
            memset(&cfg->write_allow_addrs, 0, sizeof(cfg->write_allow_addrs));
            memcpy(member, value, strlen(value) + 1);
            return 0;
        }
        if (ip_allow_parse(value, &parsed, reason, sizeof(reason)) != 0) {
            snprintf(why, why_size, "%s", reason);
            return -EINVAL;
        }
        cfg->write_allow_addrs = parsed;
        memcpy(member, value, strlen(value) + 1);
        return 0;
    }
    case KEY_PATH:
        if (strlen(value) >= k->size) {
            snprintf(why, why_size, "must be at most %zu characters", k->size - 1);
            return -EINVAL;
        }
        memcpy(member, value, strlen(value) + 1);
        return 0;
    case KEY_RIGHTS: {
        uint32_t rights;
        if (strlen(value) >= k->size) {
            snprintf(why, why_size, "must be at most %zu characters", k->size - 1);
            return -EINVAL;
        }
        if (regmap_parse_rights(value, &rights, why, why_size) != 0)
            return -EINVAL;
        *rights_mask(cfg, k) = rights;
        memcpy(member, value, strlen(value) + 1);
        return 0;
    }
    case KEY_FINGERPRINT: {
        uint8_t fp[32];
        if (strlen(value) >= k->size ||
            (value[0] && tls_parse_fingerprint(value, fp, why, why_size) != 0)) {
            if (strlen(value) >= k->size)
                snprintf(why, why_size, "must be at most %zu characters", k->size - 1);
            return -EINVAL;
        }
        memcpy(member, value, strlen(value) + 1);
        return 0;
    }
    case KEY_STRING:
    case KEY_HOST:
    case KEY_IP_ADDRESS:
        if ((value[0] == '\0' && k->min > 0) || strlen(value) >= k->size) {
            snprintf(why, why_size, "must be %u..%zu characters", k->min ? 1 : 0,
                     k->size - 1);
            return -EINVAL;
        }
        /* [tls] bind may be empty: [modbus] bind then. */
        if (k->type == KEY_IP_ADDRESS && (value[0] || k->min > 0) && !is_ip_address(value)) {
            snprintf(why, why_size, "'%s' is not an IPv4 or IPv6 address", value);
            return -EINVAL;
        }
        if (k->type == KEY_HOST && !is_ip_address(value) && !is_host_name(value)) {
            snprintf(why, why_size, "'%s' is not an IP address or a host name", value);
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
    case KEY_CHOICE:
        for (uint32_t i = 0; k->choices[i]; i++)
            if (strcasecmp(value, k->choices[i]) == 0) {
                *(uint32_t *)member = i;
                return 0;
            }
        {
            char list[96] = "";
            for (uint32_t i = 0; k->choices[i]; i++)
                snprintf(list + strlen(list), sizeof(list) - strlen(list), "%s%s",
                         i ? (k->choices[i + 1] ? ", " : " or ") : "", k->choices[i]);
            snprintf(why, why_size, "'%s' must be %s", value, list);
        }
        return -EINVAL;
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
    case KEY_BOOL:
        return parse_bool(value, member, why, why_size);
    case KEY_INTERFACE:
        return parse_interface(value, member, k->size, why, why_size);
    case KEY_CAN_ID:
        return parse_can_id(value, k->max, member, why, why_size);
    case KEY_CAN_GROUPS:
        return can_map_parse_groups(value, member, why, why_size);
    }
    return -EINVAL;
}

void config_defaults(struct gw_config *cfg)
{
    char why[128];

    memset(cfg, 0, sizeof(*cfg));
    for (size_t i = 0; i < N_KEYS; i++)
        set_key(cfg, &keys[i], keys[i].default_value, why, sizeof(why));
}

/* A robot named by the file or a flag, not the built-in default. */
static void note_named(struct gw_config *cfg, const struct key_info *k)
{
    if (k->offset == offsetof(struct gw_config, robot_host))
        cfg->robot_named = true;
}

static const struct key_info *find_key(const char *section, const char *key)
{
    for (size_t i = 0; i < N_KEYS; i++) {
        if (strcmp(keys[i].section, section) == 0 && strcmp(keys[i].key, key) == 0)
            return &keys[i];
    }
    return NULL;
}

/*
 * Why a key is unknown: "unknown key", and where it belongs when other
 * sections have it (a key put under the wrong heading is the common slip).
 */
static void explain_unknown(const char *section, const char *key, char *why, size_t size)
{
    size_t used = (size_t)snprintf(why, size, "unknown key");
    unsigned found = 0;

    for (size_t i = 0; i < N_KEYS && used < size; i++) {
        if (strcmp(keys[i].key, key) != 0 || strcmp(keys[i].section, section) == 0)
            continue;
        used += (size_t)snprintf(why + used, size - used, "%s[%s]",
                                 found++ ? " or " : " in this section; it belongs in ",
                                 keys[i].section);
    }
}

int config_set(struct gw_config *cfg, const char *section, const char *key,
               const char *value, char *why, size_t why_size)
{
    const struct key_info *k = find_key(section, key);

    if (!k) {
        explain_unknown(section, key, why, why_size);
        return -EINVAL;
    }
    if (set_key(cfg, k, value, why, why_size) != 0)
        return -EINVAL;
    note_named(cfg, k);
    return 0;
}

/*
 * The file is read whole, then handed to libinih one line at a time by
 * read_line(), so that the loader knows the number and the text of the line
 * libinih is working on. libinih's own reader (fgets into a fixed buffer)
 * cuts a long line in two, so the error named a line that does not exist
 * and no key; and it cannot see a NUL byte, which silently ended the value.
 */
#define CONFIG_MAX_FILE_BYTES (1024 * 1024)

struct load_state {
    struct gw_config *cfg;
    const char *text; /* the whole file */
    size_t size;
    size_t next;                /* offset of the next line to hand over */
    int line;                   /* number of the line last handed over */
    const char *line_start;     /* its text, without the line end */
    size_t line_len;
    char line_defect[64];       /* why that line cannot be used, or "" */
    int key_line[N_KEYS];       /* where each key was set, 0: not set */
    int error_line;             /* the first error the loader found, 0: none */
    char error[400];
};

static void fail(struct load_state *st, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/* Records the first error only: it is the one the user must fix first. */
static void fail(struct load_state *st, const char *fmt, ...)
{
    va_list ap;

    if (st->error_line)
        return;
    st->error_line = st->line;
    va_start(ap, fmt);
    vsnprintf(st->error, sizeof(st->error), fmt, ap);
    va_end(ap);
}

static bool is_comment_or_blank(const char *text, size_t len)
{
    while (len && (*text == ' ' || *text == '\t')) {
        text++;
        len--;
    }
    return len == 0 || *text == ';' || *text == '#';
}

/* An ini_reader: hands libinih the next line, at most 'size' - 1 bytes. */
static char *read_line(char *buf, int size, void *stream)
{
    struct load_state *st = stream;
    const char *start, *end;
    size_t len, usable, max = (size_t)size - 1;

    if (st->line_defect[0]) {
        /* libinih skipped the line (a comment or a [section]) without
         * calling on_ini_entry; it is refused all the same. */
        fail(st, "the line %s", st->line_defect);
        st->line_defect[0] = '\0';
    }
    if (st->error_line || st->next >= st->size)
        return NULL; /* the end of the file, for libinih */
    start = st->text + st->next;
    end = memchr(start, '\n', st->size - st->next);
    len = end ? (size_t)(end - start) : st->size - st->next;
    st->next += len + (end ? 1 : 0);
    if (len && start[len - 1] == '\r')
        len--;
    st->line++;
    st->line_start = start;
    st->line_len = len;

    usable = len;
    const char *nul = memchr(start, '\0', len);
    if (nul) {
        snprintf(st->line_defect, sizeof(st->line_defect), "contains a NUL byte");
        usable = (size_t)(nul - start);
    }
    if (usable > max) {
        /* The rest of a long comment is dropped; anything else is refused. */
        if (!is_comment_or_blank(start, usable))
            snprintf(st->line_defect, sizeof(st->line_defect), "is longer than %zu characters",
                     max);
        usable = max;
    }
    memcpy(buf, start, usable);
    buf[usable] = '\0';
    return buf;
}

/*
 * libinih calls an indented line that follows a key a continuation of its
 * value, and calls the handler again with that key and the whole line as the
 * value. No jakagw value spans lines, and an indented key that was meant as
 * a key of its own would be swallowed: it is refused.
 */
static bool is_continuation(const struct load_state *st, const char *value)
{
    const char *p = st->line_start, *end = st->line_start + st->line_len;

    if (st->line_len == 0 || (*p != ' ' && *p != '\t'))
        return false;
    while (p < end && (*p == ' ' || *p == '\t'))
        p++;
    while (end > p && isspace((unsigned char)end[-1]))
        end--;
    return (size_t)(end - p) == strlen(value) && memcmp(p, value, strlen(value)) == 0;
}

/*
 * A [roles] line: a role name as certificates carry it (UTF-8, any
 * language, no spaces or control characters, at most 63 bytes: see
 * tls_role_name_problem), each named once, and its rights.
 */
static int add_role(struct gw_config *cfg, const char *name, const char *value, char *why,
                    size_t why_size)
{
    struct config_role *r;

    const char *problem = tls_role_name_problem(name, strlen(name));

    if (strlen(name) >= sizeof(r->name)) {
        snprintf(why, why_size, "a role name is at most %zu bytes", sizeof(r->name) - 1);
        return -EINVAL;
    }
    if (problem) {
        snprintf(why, why_size,
                 "a role name is UTF-8 without spaces or control characters: %s", problem);
        return -EINVAL;
    }
    for (unsigned i = 0; i < cfg->role_count; i++) {
        if (strcmp(cfg->roles[i].name, name) == 0) {
            snprintf(why, why_size, "the role is listed twice");
            return -EINVAL;
        }
    }
    if (cfg->role_count == CONFIG_MAX_ROLES) {
        snprintf(why, why_size, "more than %d roles", CONFIG_MAX_ROLES);
        return -EINVAL;
    }
    r = &cfg->roles[cfg->role_count];
    if (strlen(value) >= sizeof(r->text)) {
        snprintf(why, why_size, "must be at most %zu characters", sizeof(r->text) - 1);
        return -EINVAL;
    }
    if (regmap_parse_rights(value, &r->rights, why, why_size) != 0)
        return -EINVAL;
    snprintf(r->name, sizeof(r->name), "%s", name);
    snprintf(r->text, sizeof(r->text), "%s", value);
    cfg->role_count++;
    return 0;
}

uint32_t config_role_rights(const struct gw_config *cfg, const char *role, bool valid,
                            bool *listed)
{
    *listed = false;
    if (valid && role[0]) {
        for (unsigned i = 0; i < cfg->role_count; i++) {
            if (strcmp(cfg->roles[i].name, role) == 0) {
                *listed = true;
                return cfg->roles[i].rights;
            }
        }
    }
    return cfg->tls_default_rights_mask;
}

static int on_ini_entry(void *user, const char *section, const char *name,
                        const char *value)
{
    struct load_state *st = user;
    const struct key_info *k;
    char reason[200];

    if (st->error_line)
        return 0;
    if (st->line_defect[0]) {
        fail(st, "[%s] %s: the line %s", section, name, st->line_defect);
        st->line_defect[0] = '\0';
        return 0;
    }
    if (is_continuation(st, value)) {
        fail(st, "[%s] %s: an indented line continues the value above; remove the "
                 "indentation",
             section, name);
        return 0;
    }
    if (section[0] == '\0') {
        fail(st, "%s: a key before any [section] line", name);
        return 0;
    }
    if (strcmp(section, "roles") == 0) {
        if (add_role(st->cfg, name, value, reason, sizeof(reason)) != 0)
            fail(st, "[roles] %s: %s", name, reason);
        return 1;
    }
    k = find_key(section, name);
    if (!k) {
        explain_unknown(section, name, reason, sizeof(reason));
        fail(st, "[%s] %s: %s", section, name, reason);
        return 0;
    }
    if (st->key_line[k - keys]) {
        fail(st, "[%s] %s: duplicate key, first set on line %d", section, name,
             st->key_line[k - keys]);
        return 0;
    }
    if (set_key(st->cfg, k, value, reason, sizeof(reason)) != 0) {
        fail(st, "[%s] %s: %s", section, name, reason);
        return 0;
    }
    note_named(st->cfg, k);
    st->key_line[k - keys] = st->line;
    return 1;
}

/* Why libinih refused line 'n', which it read without calling the handler. */
static void describe_bad_line(const struct load_state *st, int n, char *out, size_t out_size)
{
    const char *p = st->text, *end = st->text + st->size;
    char shown[64];
    size_t len, i;

    for (int line = 1; line < n && p < end; line++) {
        const char *nl = memchr(p, '\n', (size_t)(end - p));
        p = nl ? nl + 1 : end;
    }
    while (p < end && (*p == ' ' || *p == '\t'))
        p++;
    len = 0;
    while (p + len < end && p[len] != '\n' && p[len] != '\r')
        len++;
    for (i = 0; i < len && i < sizeof(shown) - 1; i++)
        shown[i] = isprint((unsigned char)p[i]) ? p[i] : '?';
    shown[i] = '\0';
    if (len && p[0] == '[')
        snprintf(out, out_size, "'%s': a [section] line must end with ']'", shown);
    else
        snprintf(out, out_size, "not a 'key = value' or [section] line: '%s'", shown);
}

static int read_whole_file(const char *path, char **text, size_t *size, char *why,
                           size_t why_size)
{
    FILE *f = fopen(path, "rb");
    struct stat sb;
    size_t cap = 4096, n = 0;
    char *buf;
    int err;

    if (!f) {
        err = errno;
        snprintf(why, why_size, "%s: cannot open: %s", path, strerror(err));
        return -err;
    }
    /* A directory opens; reading it then fails, which libinih took for an
     * empty file. */
    if (fstat(fileno(f), &sb) == 0 && S_ISDIR(sb.st_mode)) {
        snprintf(why, why_size, "%s: is a directory, not a configuration file", path);
        fclose(f);
        return -EISDIR;
    }
    buf = malloc(cap);
    while (buf) {
        size_t got;
        if (n == cap) {
            if (cap > CONFIG_MAX_FILE_BYTES)
                break;
            char *bigger = realloc(buf, cap * 2);
            if (!bigger)
                free(buf);
            buf = bigger;
            cap *= 2;
            continue;
        }
        got = fread(buf + n, 1, cap - n, f);
        if (got == 0)
            break; /* the end of the file, or an error */
        n += got;
    }
    if (!buf) {
        snprintf(why, why_size, "%s: out of memory", path);
        fclose(f);
        return -ENOMEM;
    }
    if (n > CONFIG_MAX_FILE_BYTES) {
        snprintf(why, why_size, "%s: larger than %d bytes, not a configuration file", path,
                 CONFIG_MAX_FILE_BYTES);
        free(buf);
        fclose(f);
        return -EFBIG;
    }
    if (ferror(f)) {
        err = errno ? errno : EIO;
        snprintf(why, why_size, "%s: cannot read: %s", path, strerror(err));
        free(buf);
        fclose(f);
        return -err;
    }
    fclose(f);
    *text = buf;
    *size = n;
    return 0;
}

int config_load(struct gw_config *cfg, const char *path, char *why,
                size_t why_size)
{
    char *text = NULL;
    size_t size = 0;
    char reason[200];
    int rc;

    rc = read_whole_file(path, &text, &size, why, why_size);
    if (rc)
        return rc;
    struct load_state st = {.cfg = cfg, .text = text, .size = size};
    rc = ini_parse_stream(read_line, &st, on_ini_entry, &st);
    if (st.line_defect[0]) /* the last line, skipped by libinih */
        fail(&st, "the line %s", st.line_defect);
    if (rc < 0) {
        snprintf(why, why_size, "%s: out of memory", path);
        rc = -ENOMEM;
    } else if (rc > 0 && (st.error_line == 0 || rc < st.error_line)) {
        /* libinih goes on after a line it cannot parse; it was the first. */
        describe_bad_line(&st, rc, reason, sizeof(reason));
        snprintf(why, why_size, "%s:%d: %s", path, rc, reason);
        rc = -EINVAL;
    } else if (st.error_line) {
        snprintf(why, why_size, "%s:%d: %s", path, st.error_line, st.error);
        rc = -EINVAL;
    }
    free(text);
    return rc;
}

int config_validate(const struct gw_config *cfg, char *why, size_t why_size)
{
    if (!cfg->modbus_enabled && !cfg->tls_enabled && !cfg->rtu_enabled) {
        snprintf(why, why_size,
                 "[modbus] enabled: false leaves nothing to serve without [tls] enabled = true "
                 "or [rtu] enabled = true");
        return -EINVAL;
    }
    if (cfg->tls_enabled) {
        static const struct { const char *key; size_t offset; } needed[] = {
            {"certificate", offsetof(struct gw_config, tls_certificate)},
            {"private_key", offsetof(struct gw_config, tls_private_key)},
            {"client_ca", offsetof(struct gw_config, tls_client_ca)},
        };
        for (size_t i = 0; i < sizeof(needed) / sizeof(needed[0]); i++) {
            if (((const char *)cfg + needed[i].offset)[0] == '\0') {
                snprintf(why, why_size, "[tls] %s: required with [tls] enabled = true",
                         needed[i].key);
                return -EINVAL;
            }
        }
        if (cfg->modbus_enabled && cfg->tls_port == cfg->modbus_port &&
            (cfg->tls_bind[0] == '\0' || strcmp(cfg->tls_bind, cfg->modbus_bind) == 0)) {
            snprintf(why, why_size, "[tls] port: %u is [modbus] port too", cfg->tls_port);
            return -EINVAL;
        }
    }
    if (cfg->rtu_enabled) {
        static const unsigned bauds[] = {1200, 2400, 4800, 9600, 19200, 38400, 57600,
                                         115200, 230400, 460800, 921600};
        bool known = false;
        for (size_t i = 0; i < sizeof(bauds) / sizeof(bauds[0]); i++)
            known = known || bauds[i] == cfg->rtu_baud;
        if (cfg->rtu_device[0] == '\0') {
            snprintf(why, why_size, "[rtu] device: required with [rtu] enabled = true");
            return -EINVAL;
        }
        if (!known) {
            snprintf(why, why_size,
                     "[rtu] baud: %u is not a serial speed: 1200, 2400, 4800, 9600, 19200, "
                     "38400, 57600, 115200, 230400, 460800 or 921600",
                     cfg->rtu_baud);
            return -EINVAL;
        }
    }
    if (cfg->robot_tls && !cfg->robot_tls_ca[0] && !cfg->robot_tls_fingerprint[0]) {
        snprintf(why, why_size,
                 "[robot] tls: true needs tls_ca or tls_fingerprint to trust the controller");
        return -EINVAL;
    }
    if (cfg->reconnect_min_ms > cfg->reconnect_max_ms) {
        snprintf(why, why_size,
                 "[robot] reconnect_min_ms: %u exceeds reconnect_max_ms %u",
                 cfg->reconnect_min_ms, cfg->reconnect_max_ms);
        return -EINVAL;
    }
    if (cfg->can_enabled) {
        uint32_t max_id = cfg->can_extended_ids ? CAN_MAX_EXT_ID : CAN_MAX_STD_ID;
        if (cfg->can_interface[0] == '\0') {
            snprintf(why, why_size, "[can] enabled: true needs an interface");
            return -EINVAL;
        }
        if (cfg->can_base_id > max_id - can_map_max_offset()) {
            snprintf(why, why_size,
                     "[can] base_id: 0x%X leaves no room for the frames: at most 0x%X "
                     "with %s identifiers",
                     cfg->can_base_id, max_id - can_map_max_offset(),
                     cfg->can_extended_ids ? "extended" : "standard (11-bit)");
            return -EINVAL;
        }
    }
    return 0;
}

/* A value as text, escaped as the log escapes it: one line, no control bytes. */
static void print_text(FILE *out, const char *text)
{
    char shown[CONFIG_TEXT_SHOWN];

    log_escape(shown, sizeof(shown), text, strlen(text));
    fprintf(out, "%s\n", shown);
}

size_t config_key_count(void)
{
    return N_KEYS;
}

const char *config_key_section(size_t i)
{
    return i < N_KEYS ? keys[i].section : NULL;
}

const char *config_key_name(size_t i)
{
    return i < N_KEYS ? keys[i].key : NULL;
}

/* A fingerprint's 32 bytes, or all zero for none (or, never stored, a bad one). */
static void fingerprint_bytes(const char *text, uint8_t out[32])
{
    char why[96];

    memset(out, 0, 32);
    if (text[0] && tls_parse_fingerprint(text, out, why, sizeof(why)) != 0)
        memset(out, 0, 32);
}

bool config_key_equal(const struct gw_config *a, const struct gw_config *b, size_t i)
{
    const struct key_info *k = &keys[i];
    const void *ma = (const char *)a + k->offset, *mb = (const char *)b + k->offset;

    if (i >= N_KEYS)
        return false;
    switch (k->type) {
    case KEY_STRING:
    case KEY_HOST:
    case KEY_IP_ADDRESS:
    case KEY_PATH:
    case KEY_INTERFACE:
        return strcmp(ma, mb) == 0;
    case KEY_IP_LIST:
        /* The addresses, as parsed: the same list however it is spelt. */
        if (config_writes_from_nobody(a) != config_writes_from_nobody(b) ||
            a->write_allow_addrs.count != b->write_allow_addrs.count)
            return false;
        for (unsigned n = 0; n < a->write_allow_addrs.count; n++)
            if (memcmp(&a->write_allow_addrs.addrs[n], &b->write_allow_addrs.addrs[n],
                       sizeof(struct in6_addr)) != 0)
                return false;
        return true;
    case KEY_RIGHTS:
        return *(const uint32_t *)((const char *)a + rights_mask_offset(k)) ==
               *(const uint32_t *)((const char *)b + rights_mask_offset(k));
    case KEY_FINGERPRINT: {
        uint8_t fa[32], fb[32];
        fingerprint_bytes(ma, fa);
        fingerprint_bytes(mb, fb);
        return memcmp(fa, fb, sizeof(fa)) == 0;
    }
    case KEY_UNIT_ID:
        return *(const int32_t *)ma == *(const int32_t *)mb;
    case KEY_BOOL:
        return *(const bool *)ma == *(const bool *)mb;
    case KEY_UINT:
    case KEY_CHOICE:
    case KEY_WORD_ORDER:
    case KEY_LOG_LEVEL:
    case KEY_CAN_ID:
    case KEY_CAN_GROUPS:
        return *(const uint32_t *)ma == *(const uint32_t *)mb;
    }
    return false;
}

void config_key_format(const struct gw_config *cfg, size_t i, char *out, size_t size)
{
    const struct key_info *k = &keys[i];
    const void *m = (const char *)cfg + k->offset;

    if (i >= N_KEYS || size == 0)
        return;
    switch (k->type) {
    case KEY_STRING:
    case KEY_HOST:
    case KEY_IP_ADDRESS:
    case KEY_IP_LIST:
    case KEY_PATH:
    case KEY_RIGHTS:
    case KEY_FINGERPRINT:
    case KEY_INTERFACE:
        log_escape(out, size, (const char *)m, strlen((const char *)m));
        break;
    case KEY_UINT:
        snprintf(out, size, "%u", *(const uint32_t *)m);
        break;
    case KEY_UNIT_ID:
        if (*(const int32_t *)m < 0)
            snprintf(out, size, "any");
        else
            snprintf(out, size, "%d", *(const int32_t *)m);
        break;
    case KEY_CHOICE:
        snprintf(out, size, "%s", k->choices[*(const uint32_t *)m]);
        break;
    case KEY_WORD_ORDER:
        snprintf(out, size, "%s", *(const uint32_t *)m ? "low_first" : "high_first");
        break;
    case KEY_LOG_LEVEL:
        snprintf(out, size, "%s", log_level_names[*(const uint32_t *)m]);
        break;
    case KEY_BOOL:
        snprintf(out, size, "%s", *(const bool *)m ? "true" : "false");
        break;
    case KEY_CAN_ID:
        snprintf(out, size, "0x%X", *(const uint32_t *)m);
        break;
    case KEY_CAN_GROUPS:
        can_map_format_groups(*(const uint32_t *)m, out, size);
        break;
    }
}

void config_print(const struct gw_config *cfg, FILE *out)
{
    const char *section = "";
    char shown[CONFIG_TEXT_SHOWN];

    for (size_t i = 0; i < N_KEYS; i++) {
        const struct key_info *k = &keys[i];
        if (strcmp(section, k->section) != 0) {
            fprintf(out, "%s[%s]\n", i ? "\n" : "", k->section);
            section = k->section;
        }
        config_key_format(cfg, i, shown, sizeof(shown));
        fprintf(out, "%s = %s\n", k->key, shown);
    }
    /* Last: [roles] is a list, not a key of the table. */
    if (cfg->role_count)
        fprintf(out, "\n[roles]\n");
    for (unsigned i = 0; i < cfg->role_count; i++) {
        char name[6 * sizeof(cfg->roles[i].name)];
        log_escape(name, sizeof(name), cfg->roles[i].name, strlen(cfg->roles[i].name));
        fprintf(out, "%s = ", name);
        print_text(out, cfg->roles[i].text);
    }
}

bool config_writes_from_nobody(const struct gw_config *cfg)
{
    return strcmp(cfg->write_allow, CONFIG_WRITE_ALLOW_NONE) == 0;
}

void config_describe_writes(const struct gw_config *cfg, char *out, size_t size)
{
    if (cfg->read_only)
        snprintf(out, size, "from no client: [modbus] read_only = true");
    else if (config_writes_from_nobody(cfg))
        snprintf(out, size, "from no Modbus TCP client until [modbus] write_allow names the "
                            "PLCs that may write (it is 'none'); TLS clients by their role");
    else if (cfg->write_allow_addrs.count == 0)
        snprintf(out, size, "from any client: [modbus] write_allow is empty; name the PLCs "
                            "that may write");
    else
        snprintf(out, size, "from %s only ([modbus] write_allow)", cfg->write_allow);
}
