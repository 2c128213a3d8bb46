/* SPDX-License-Identifier: MIT */
/*
 * config.h - jakagw's settings: defaults, INI file (libinih), flags.
 *
 * Every key lives in one table (src/core/config.c) that gives its section, type,
 * range and default; the INI parser and the command-line overrides both set
 * keys through config_set(), so a bad value gets the same one-line answer
 * wherever it comes from. Unknown keys are errors: a typo must not silently
 * leave a default in force on a machine that drives a robot.
 */
#ifndef JAKAGW_CONFIG_H
#define JAKAGW_CONFIG_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "ip_allow.h"
#include "regmap.h"

#define CONFIG_DEFAULT_PATH "/etc/jakagw/jakagw.conf"
#define CONFIG_MAX_WRITE_ALLOW IP_ALLOW_MAX
#define CONFIG_MAX_ROLES 32

/* One line of [roles]: a certificate role and what it may write. */
struct config_role {
    char name[64];
    char text[160];  /* as written: read, write, or classes */
    uint32_t rights; /* the same, parsed (regmap_parse_rights) */
};

struct gw_config {
    /* [robot] */
    char robot_host[256];
    /* Not a key: [robot] host was set by the file or a flag, not left at
     * its default. A service is not started until it is (--check-start). */
    bool robot_named;
    uint32_t status_port;
    uint32_t command_port;
    uint32_t connect_timeout_ms;
    uint32_t reconnect_min_ms;
    uint32_t reconnect_max_ms;
    uint32_t status_timeout_ms;
    uint32_t link_check_ms; /* an idle command link is checked this often */
    uint32_t max_document_bytes;
    bool robot_tls;              /* both robot ports over TLS */
    char robot_tls_ca[256];      /* the controller's CA, PEM */
    char robot_tls_fingerprint[100]; /* or its certificate's SHA-256 */
    /* [modbus] */
    bool modbus_enabled;   /* the plain listener */
    char modbus_bind[64];
    uint32_t modbus_port;
    uint32_t max_clients;
    uint32_t idle_timeout_ms; /* 0: never */
    uint32_t frame_timeout_ms;
    int32_t unit_id; /* -1: any */
    uint32_t word_order; /* enum regmap_word_order */
    /* Not a key: a listening socket passed by systemd, 0: bind and port. */
    int modbus_listen_fd;
    bool read_only;        /* no Modbus write at all */
    char write_allow[400]; /* client addresses that may write, as written; "" any,
                            * "none" no plain Modbus TCP client */
    struct ip_allow write_allow_addrs; /* the same, parsed once when set */
    /* [commands] */
    bool motion;             /* motion commands allowed */
    bool allow_shutdown;     /* the shutdown command allowed */
    uint32_t reply_timeout_ms;
    /* [network_exception] */
    uint32_t ne_time_limit_ms;
    uint32_t ne_action;      /* enum policy_action */
    uint32_t ne_watch;       /* enum policy_watch - 1 */
    bool ne_motion_enable;
    bool ne_single_owner;
    uint32_t ne_owner;       /* 0 host, 1 connection */
    uint32_t ne_stop_time_ms; /* the robot's stopping time */
    bool ne_require_heartbeat;
    uint32_t ne_robot_time_limit_ms;
    uint32_t ne_robot_action; /* motType: 0 keep, 1 pause, 2 stop */
    bool ne_require_robot_handle;
    /* [log] */
    uint32_t log_level; /* enum log_level */
    /* [can] */
    bool can_enabled;
    char can_interface[16]; /* IF_NAMESIZE; "" none */
    uint32_t can_base_id;
    bool can_extended_ids;
    uint32_t can_period_ms;
    uint32_t can_groups; /* bit per enum can_group */
    /* [tls]: the Modbus/TCP Security listener */
    bool tls_enabled;
    char tls_bind[64]; /* "": [modbus] bind */
    uint32_t tls_port;
    char tls_certificate[256];
    char tls_private_key[256]; /* a path, or a systemd credential's name */
    char tls_client_ca[256];
    char tls_crl[256];
    uint32_t tls_min_version; /* 0: 1.2, 1: 1.3 */
    uint32_t tls_handshake_timeout_ms;
    uint32_t tls_max_handshakes;
    char tls_default_rights[160]; /* as written */
    uint32_t tls_default_rights_mask;
    /* Not a key: a listening socket for [tls] passed by systemd, 0: none. */
    int tls_listen_fd;
    /* [rtu]: Modbus RTU on a serial line (mb_rtu.h) */
    bool rtu_enabled;
    char rtu_device[256];
    uint32_t rtu_baud;
    uint32_t rtu_parity;    /* enum mb_rtu_parity: none, even, odd */
    uint32_t rtu_stop_bits; /* 1 or 2 */
    uint32_t rtu_unit_id;   /* 1..247 */
    bool rtu_rs485;         /* TIOCSRS485 */
    bool rtu_local_echo;    /* the adapter gives back what it sends */
    uint32_t rtu_delivery_ms; /* the adapter's delivery bound where sysfs tells none */
    char rtu_rights[160];   /* as written */
    uint32_t rtu_rights_mask;
    /* [http]: metrics, status page */
    bool http_enabled;
    char http_bind[64];
    uint32_t http_port;
    /* [roles] */
    struct config_role roles[CONFIG_MAX_ROLES];
    unsigned role_count;
};

/* Fills 'cfg' with the defaults. */
void config_defaults(struct gw_config *cfg);

/*
 * Sets one key from text. Returns 0, or -EINVAL with a reason ("not a
 * number", "must be 1..65535", "unknown key") written to 'why'. [modbus]
 * bind must be a literal IPv4 or IPv6 address; [robot] host an address or a
 * host name.
 */
int config_set(struct gw_config *cfg, const char *section, const char *key,
               const char *value, char *why, size_t why_size);

/*
 * Reads an INI file over 'cfg', with "FILE: reason" or
 * "FILE:LINE: [section] key: reason" written to 'why' on failure. Returns 0;
 * -ENOENT when the file does not exist (only then may a caller fall back to
 * the defaults); another negative errno when it cannot be opened or read,
 * -EISDIR for a directory, -EFBIG above 1 MiB; -EINVAL for the first bad line:
 * a bad value, an unknown or duplicate key, a key outside a section or on an
 * indented (continuation) line, an unterminated [section], a NUL byte, or a
 * line longer than libinih's line buffer (INI_MAX_LINE - 1 characters; longer
 * comments are allowed).
 */
int config_load(struct gw_config *cfg, const char *path, char *why,
                size_t why_size);

/* Checks rules between keys. Returns 0 or -EINVAL with the reason. */
int config_validate(const struct gw_config *cfg, char *why, size_t why_size);

/*
 * The rights of a certificate role: its [roles] line (*listed set), or
 * default_rights for "" (no role), a role no line names, or !valid.
 */
uint32_t config_role_rights(const struct gw_config *cfg, const char *role, bool valid,
                            bool *listed);

/* Writes the effective configuration as INI (for --check-config). */
void config_print(const struct gw_config *cfg, FILE *out);

/*
 * The key table, for comparing two configurations (config_reload.c): key
 * i (0 .. config_key_count() - 1), its section and name; whether two
 * configurations hold the same value for it, compared as its type has it
 * (numbers and choices as numbers, write_allow as the addresses parsed,
 * default_rights as the rights, a fingerprint as its bytes, names and
 * paths as text); and its value as --check-config prints it (escaped).
 * [roles] is not in the table.
 */
#define CONFIG_TEXT_SHOWN (6 * 200 + 1) /* any value (at most 199 bytes), escaped */
size_t config_key_count(void);
const char *config_key_section(size_t i);
const char *config_key_name(size_t i);
bool config_key_equal(const struct gw_config *a, const struct gw_config *b, size_t i);
void config_key_format(const struct gw_config *cfg, size_t i, char *out, size_t size);

/* [modbus] write_allow = none: no plain Modbus TCP client may write (TLS
 * clients write as their role allows). */
#define CONFIG_WRITE_ALLOW_NONE "none"
bool config_writes_from_nobody(const struct gw_config *cfg);

/* Who may write, in words, for the log and the status page: "from any
 * client: ...", "from 10.0.0.5 only ...". */
void config_describe_writes(const struct gw_config *cfg, char *out, size_t size);

#endif
