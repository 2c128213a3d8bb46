/* SPDX-License-Identifier: MIT */
/* test_config.c - configuration keys, files and their error messages. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <ini.h>

#include "config.h"
#include "config_reload.h"

static char path[64];

/* Writes 'size' bytes, so a test can put a NUL byte in the file. */
static void write_conf_bytes(const char *text, size_t size)
{
    snprintf(path, sizeof(path), "/tmp/jakagw-test-%d.conf", (int)getpid());
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    assert_int_equal(fwrite(text, 1, size, f), size);
    fclose(f);
}

static void write_conf(const char *text)
{
    write_conf_bytes(text, strlen(text));
}

/* Loads 'text' over the defaults; expects -EINVAL and 'expect' in the reason. */
static void expect_refused(const char *text, size_t size, const char *expect)
{
    struct gw_config c;
    char why[512];

    config_defaults(&c);
    write_conf_bytes(text, size);
    int rc = config_load(&c, path, why, sizeof(why));
    unlink(path);
    if (rc != -EINVAL)
        fail_msg("'%s': returned %d, expected -EINVAL", text, rc);
    if (!strstr(why, expect))
        fail_msg("'%s' lacks '%s'", why, expect);
}

static void expect_loaded(const char *text, struct gw_config *c)
{
    char why[512];

    config_defaults(c);
    write_conf(text);
    int rc = config_load(c, path, why, sizeof(why));
    unlink(path);
    if (rc != 0)
        fail_msg("refused: %s", why);
}

static void defaults(void **state)
{
    (void)state;
    struct gw_config c;
    config_defaults(&c);
    assert_string_equal(c.robot_host, "127.0.0.1");
    assert_int_equal(c.status_port, 10000);
    assert_int_equal(c.command_port, 10001);
    assert_int_equal(c.modbus_port, 502);
    assert_int_equal(c.max_clients, 32);
    assert_int_equal(c.unit_id, -1);
    assert_int_equal(c.word_order, REGMAP_HIGH_WORD_FIRST);
    assert_int_equal(c.max_document_bytes, 65536);
    /* The PLC contract: the owner is the heartbeat's connection, no motion
     * without a heartbeat, braking counts as stopping for 1.5 s. */
    assert_int_equal(c.ne_owner, 1);
    assert_int_equal(c.ne_stop_time_ms, 1500);
    assert_true(c.ne_require_heartbeat);
}

static void owner_and_require_heartbeat(void **state)
{
    (void)state;
    struct gw_config c;
    static const char bad_owner[] = "[network_exception]\nowner = socket\n";
    static const char bad_bool[] = "[network_exception]\nrequire_heartbeat = maybe\n";
    expect_loaded("[network_exception]\nowner = connection\nrequire_heartbeat = false\n", &c);
    assert_int_equal(c.ne_owner, 1);
    assert_false(c.ne_require_heartbeat);
    expect_loaded("[network_exception]\nowner = host\n", &c);
    assert_int_equal(c.ne_owner, 0);
    expect_refused(bad_owner, sizeof(bad_owner) - 1, "[network_exception] owner");
    expect_refused(bad_bool, sizeof(bad_bool) - 1, "[network_exception] require_heartbeat");
}

static void file_overrides_defaults(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];
    config_defaults(&c);
    write_conf("; comment\n[robot]\nhost = 10.0.0.7\nstatus_timeout_ms = 250\n"
               "[modbus]\nport=1502\nunit_id = 17\nword_order = CDAB\n"
               "[log]\nlevel = debug\n");
    assert_int_equal(config_load(&c, path, why, sizeof(why)), 0);
    assert_string_equal(c.robot_host, "10.0.0.7");
    assert_int_equal(c.status_timeout_ms, 250);
    assert_int_equal(c.modbus_port, 1502);
    assert_int_equal(c.unit_id, 17);
    assert_int_equal(c.word_order, REGMAP_LOW_WORD_FIRST);
    unlink(path);
}

static void bad_values_name_key_and_line(void **state)
{
    (void)state;
    static const struct { const char *text, *expect; } cases[] = {
        {"[robot]\nstatus_port = 0\n", ":2: [robot] status_port: 0 is out of range 1..65535"},
        {"[modbus]\nport = 5o2\n", ":2: [modbus] port: '5o2' is not a whole number"},
        {"[modbus]\n\nmax_clients = -3\n", ":3: [modbus] max_clients: '-3' is not a whole number"},
        {"[robot]\nhots = x\n", ":2: [robot] hots: unknown key"},
        /* A key under the wrong heading: the error says where it belongs. */
        {"[modbus]\ntime_limit_ms = 500\n",
         ":2: [modbus] time_limit_ms: unknown key in this section; it belongs in "
         "[network_exception]"},
        {"[robot]\nport = 502\n", "it belongs in [modbus] or [tls] or [http]"},
        {"[modbus]\nword_order = middle\n", "must be high_first or low_first"},
        {"[modbus]\nunit_id = 300\n", "must be 'any' or 0..255"},
        {"this is not ini\n", ":1: not a 'key = value' or [section] line"},
    };
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        struct gw_config c;
        char why[256];
        config_defaults(&c);
        write_conf(cases[i].text);
        assert_int_equal(config_load(&c, path, why, sizeof(why)), -EINVAL);
        if (!strstr(why, cases[i].expect))
            fail_msg("'%s' lacks '%s'", why, cases[i].expect);
    }
    unlink(path);
}

static void missing_file(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];
    config_defaults(&c);
    assert_int_equal(config_load(&c, "/nonexistent/jakagw.conf", why, sizeof(why)),
                     -ENOENT);
    assert_non_null(strstr(why, "cannot open"));
}

/* A directory opens and reads as an empty file with libinih's ini_parse. */
static void directory_is_refused(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];
    config_defaults(&c);
    assert_int_equal(config_load(&c, "/tmp", why, sizeof(why)), -EISDIR);
    assert_non_null(strstr(why, "/tmp: is a directory"));
}

/* Only a file that does not exist is "missing": the default path may be
 * absent, but a file that is there and cannot be read is an error. */
static void unreadable_path_is_not_missing(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256], below_a_file[128];
    config_defaults(&c);
    write_conf("");
    snprintf(below_a_file, sizeof(below_a_file), "%s/jakagw.conf", path);
    assert_int_equal(config_load(&c, below_a_file, why, sizeof(why)), -ENOTDIR);
    unlink(path);
    assert_non_null(strstr(why, "cannot open"));
}

/* The Modbus bind address is used as a literal by uv_ip4_addr/uv_ip6_addr;
 * anything else passed --check-config and then failed at start. */
static void modbus_bind_must_be_an_ip_address(void **state)
{
    (void)state;
    static const char *const good[] = {"0.0.0.0", "127.0.0.1", "::", "::1", "fe80::1"};
    static const char *const bad[] = {"not-an-ip", "999.1.1.1", "localhost", "1.2.3",
                                      "127.0.0.1 ", "[::1]"};
    struct gw_config c;
    char why[256];

    config_defaults(&c);
    for (size_t i = 0; i < sizeof(good) / sizeof(*good); i++)
        if (config_set(&c, "modbus", "bind", good[i], why, sizeof(why)) != 0)
            fail_msg("bind '%s' refused: %s", good[i], why);
    for (size_t i = 0; i < sizeof(bad) / sizeof(*bad); i++) {
        if (config_set(&c, "modbus", "bind", bad[i], why, sizeof(why)) != -EINVAL)
            fail_msg("bind '%s' accepted", bad[i]);
        assert_non_null(strstr(why, "is not an IPv4 or IPv6 address"));
    }
    const char *text = "[modbus]\nbind = 999.1.1.1\n";
    expect_refused(text, strlen(text), ":2: [modbus] bind: '999.1.1.1' is not an IPv4 or IPv6 address");
}

/* The robot host may be a name (resolved when connecting), but not one that
 * no resolver could ever accept. */
static void robot_host_is_an_address_or_a_host_name(void **state)
{
    (void)state;
    static const char *const good[] = {"10.0.0.7", "::1", "robot", "robot-1.cell.example",
                                       "robot_a.local."};
    static const char *const bad[] = {"999.1.1.1", "10.0.0", "robot 1", "-robot", "robot..lan",
                                      "status_port = 10001"};
    struct gw_config c;
    char why[256];

    config_defaults(&c);
    for (size_t i = 0; i < sizeof(good) / sizeof(*good); i++)
        if (config_set(&c, "robot", "host", good[i], why, sizeof(why)) != 0)
            fail_msg("host '%s' refused: %s", good[i], why);
    for (size_t i = 0; i < sizeof(bad) / sizeof(*bad); i++)
        if (config_set(&c, "robot", "host", bad[i], why, sizeof(why)) != -EINVAL)
            fail_msg("host '%s' accepted", bad[i]);
}

/* libinih's buffer holds lines of INI_MAX_LINE - 1 characters; a longer one
 * was cut in two, reported a line too far and never named its key. */
static void long_line_names_key_and_line(void **state)
{
    (void)state;
    const int limit = INI_MAX_LINE - 1;
    char text[1024], host[512];
    struct gw_config c;

    /* Labels of 63 characters at most keep the host a valid name. */
    for (int i = 0; i < limit - 7; i++)
        host[i] = (i % 64 == 63) ? '.' : 'h';
    host[limit - 7] = '\0';
    snprintf(text, sizeof(text), "[robot]\nhost = %s\n", host);
    expect_loaded(text, &c);
    assert_string_equal(c.robot_host, host);

    snprintf(text, sizeof(text), "[robot]\nhost = %sh\n", host);
    char expect[128];
    snprintf(expect, sizeof(expect), ":2: [robot] host: the line is longer than %d characters",
             limit);
    expect_refused(text, strlen(text), expect);

    /* A long comment is harmless, and the lines after it keep their numbers. */
    memset(host, 'c', 300);
    host[300] = '\0';
    snprintf(text, sizeof(text), "[robot]\n; %s\nstatus_port = 10002\n", host);
    expect_loaded(text, &c);
    assert_int_equal(c.status_port, 10002);
    snprintf(text, sizeof(text), "[robot]\n; %s\nhots = x\n", host);
    expect_refused(text, strlen(text), ":3: [robot] hots: unknown key");
    /* A section line cut by the limit is named as too long, not as bad. */
    snprintf(text, sizeof(text), "[%s]\n", host);
    expect_refused(text, strlen(text), ":1: the line is longer than");
    /* So is a key that starts past the limit. */
    memset(host, ' ', 300);
    snprintf(text, sizeof(text), "[robot]\n%sstatus_port = 1\n", host);
    expect_refused(text, strlen(text), ":2: the line is longer than");
}

/* libinih kept the section before the bad line, so the next key was
 * reported instead: "[] port: unknown key". */
static void unterminated_section_is_named(void **state)
{
    (void)state;
    const char *text = "[modbus\nport = 1502\n";
    expect_refused(text, strlen(text), ":1: '[modbus': a [section] line must end with ']'");
    text = "[robot]\nhost = 10.0.0.7\n[modbus ; note]\nport = 1502\n";
    expect_refused(text, strlen(text), ":3: '[modbus ; note]': a [section] line must end");
}

/* "port = 15\0 02" was read as 15. */
static void nul_byte_is_refused(void **state)
{
    (void)state;
    static const char text[] = "[modbus]\nport = 15\0 02\n";
    expect_refused(text, sizeof(text) - 1, ":2: [modbus] port: the line contains a NUL byte");
    static const char comment[] = "[modbus]\n; a\0b\nport = 1502\n";
    expect_refused(comment, sizeof(comment) - 1, ":2: the line contains a NUL byte");
    static const char last[] = "[modbus]\n\0";
    expect_refused(last, sizeof(last) - 1, ":2: the line contains a NUL byte");
}

/* The same key twice in a section: one of them was silently ignored. */
static void duplicate_key_names_both_lines(void **state)
{
    (void)state;
    const char *text = "[modbus]\nport = 1502\n\nport = 1503\n";
    expect_refused(text, strlen(text), ":4: [modbus] port: duplicate key, first set on line 2");
    text = "[modbus]\nport = 1502\n[robot]\nhost = r\n[modbus]\nport = 1502\n";
    expect_refused(text, strlen(text), ":6: [modbus] port: duplicate key, first set on line 2");
}

/* libinih goes on after a bad line; the reason given must be the first
 * bad line's, not the last one's. */
static void first_error_is_reported(void **state)
{
    (void)state;
    const char *text = "[modbus]\nport = x\nmax_clients = y\n";
    expect_refused(text, strlen(text), ":2: [modbus] port: 'x' is not a whole number");
    text = "[modbus]\nthis is not ini\nmax_clients = y\n";
    expect_refused(text, strlen(text), ":2: not a 'key = value' or [section] line");
}

/* libinih takes an indented line as the continuation of the value above:
 * "host = robot1" then "  status_port = 10001" set host to
 * "status_port = 10001". */
static void indented_continuation_is_refused(void **state)
{
    (void)state;
    const char *text = "[robot]\nhost = robot1\n  status_port = 10001\n";
    expect_refused(text, strlen(text),
                   ":3: [robot] host: an indented line continues the value above");
    /* Indented keys right after a section line are ordinary keys. */
    struct gw_config c;
    expect_loaded("[robot]\n  status_port = 10005\n", &c);
    assert_int_equal(c.status_port, 10005);
}

static void key_before_any_section(void **state)
{
    (void)state;
    const char *text = "; settings\nport = 1502\n";
    expect_refused(text, strlen(text), ":2: port: a key before any [section] line");
}

/* A 14 MB document stalled the event loop for over a second; a real one is
 * about 9 KB. */
static void max_document_bytes_at_its_limits(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];
    config_defaults(&c);
    assert_int_equal(config_set(&c, "robot", "max_document_bytes", "262144", why, sizeof(why)),
                     0);
    assert_int_equal(c.max_document_bytes, 262144);
    assert_int_equal(config_set(&c, "robot", "max_document_bytes", "262145", why, sizeof(why)),
                     -EINVAL);
    assert_string_equal(why, "262145 is out of range 65536..262144");
    assert_int_equal(config_set(&c, "robot", "max_document_bytes", "65535", why, sizeof(why)),
                     -EINVAL);
    assert_int_equal(config_set(&c, "robot", "max_document_bytes", "65536", why, sizeof(why)),
                     0);
}

static void rules_between_keys(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];
    config_defaults(&c);
    assert_int_equal(config_set(&c, "robot", "reconnect_min_ms", "9000", why, sizeof(why)), 0);
    assert_int_equal(config_validate(&c, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "reconnect_min_ms"));
}

/* A literal, refused with a reason that contains 'expect'. */
#define REFUSED(text, expect) expect_refused(text, sizeof(text) - 1, expect)

static void rtu_keys(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];

    config_defaults(&c);
    assert_false(c.rtu_enabled);
    assert_int_equal(c.rtu_baud, 19200);
    assert_int_equal(c.rtu_parity, 1); /* even */
    assert_int_equal(c.rtu_stop_bits, 1);
    assert_int_equal(c.rtu_unit_id, 1);
    assert_false(c.rtu_rs485);
    assert_int_equal(c.rtu_rights_mask, REGMAP_RIGHTS_NONE);
    expect_loaded("[rtu]\nenabled = true\ndevice = /dev/ttyS1\nbaud = 115200\nparity = none\n"
                  "stop_bits = 2\nunit_id = 247\nrs485 = true\nrights = power, heartbeat\n",
                  &c);
    assert_int_equal(config_validate(&c, why, sizeof(why)), 0);
    assert_int_equal(c.rtu_parity, 0);
    assert_int_equal(c.rtu_unit_id, 247);
    assert_true(c.rtu_rights_mask & REGMAP_RIGHT(REGMAP_CLASS_POWER));
    assert_false(c.rtu_rights_mask & REGMAP_RIGHT(REGMAP_CLASS_MOTION));
    /* [tls] default_rights keeps its own mask. */
    assert_int_equal(c.tls_default_rights_mask, REGMAP_RIGHTS_NONE);
    REFUSED("[rtu]\nunit_id = 0\n", "[rtu] unit_id: 0 is out of range 1..247");
    REFUSED("[rtu]\nunit_id = 248\n", "1..247");
    REFUSED("[rtu]\nparity = mark\n", "'mark' must be none, even or odd");
    REFUSED("[rtu]\nstop_bits = 3\n", "1..2");
    REFUSED("[rtu]\nrights = fly\n", "'fly' is not a write class");
    /* Between keys: a device, and a speed a serial port has. */
    config_defaults(&c);
    assert_int_equal(config_set(&c, "rtu", "enabled", "true", why, sizeof(why)), 0);
    assert_int_equal(config_validate(&c, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "[rtu] device: required"));
    assert_int_equal(config_set(&c, "rtu", "device", "/dev/ttyS1", why, sizeof(why)), 0);
    assert_int_equal(config_set(&c, "rtu", "baud", "12345", why, sizeof(why)), 0);
    assert_int_equal(config_validate(&c, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "[rtu] baud: 12345 is not a serial speed"));
    /* The line alone is something to serve. */
    assert_int_equal(config_set(&c, "rtu", "baud", "9600", why, sizeof(why)), 0);
    assert_int_equal(config_set(&c, "modbus", "enabled", "false", why, sizeof(why)), 0);
    assert_int_equal(config_validate(&c, why, sizeof(why)), 0);
}

static void shipped_config_is_valid(void **state)
{
    (void)state;
    struct gw_config c, d;
    char why[256];
    config_defaults(&c);
    config_defaults(&d);
    assert_int_equal(config_load(&c, CONFIG_FILE, why, sizeof(why)), 0);
    /* It names the robot (its default), which the defaults alone do not. */
    assert_true(c.robot_named);
    assert_false(d.robot_named);
    c.robot_named = false;
    /* The shipped file documents the defaults: loading it changes nothing. */
    assert_memory_equal(&c, &d, sizeof(c));
}

/* The index of [section] key in the key table. */
static size_t key_index(const char *section, const char *key)
{
    for (size_t i = 0; i < config_key_count(); i++)
        if (strcmp(config_key_section(i), section) == 0 && strcmp(config_key_name(i), key) == 0)
            return i;
    fail_msg("no key [%s] %s", section, key);
    return 0;
}

/*
 * A reload compares configurations key by key as each key's type has it:
 * the same value spelt another way is no change (no "needs a restart"
 * line), a different value is one, and only that key differs.
 */
static void keys_compare_by_type(void **state)
{
    static const char *const same[][4] = {
        /* section, key, one spelling, another */
        {"robot", "tls_fingerprint",
         "AB:CD:EF:01:23:45:67:89:AB:CD:EF:01:23:45:67:89:AB:CD:EF:01:23:45:67:89:AB:CD:EF:01:23:45:67:89",
         "abcdef0123456789abcdef0123456789abcdef0123456789abcdef0123456789"},
        {"modbus", "write_allow", "10.0.0.1, 10.0.0.2", "10.0.0.1,10.0.0.2"},
        {"modbus", "write_allow", "::ffff:10.0.0.1", "10.0.0.1"},
        {"modbus", "unit_id", "any", "ANY"},
        {"modbus", "word_order", "high_first", "ABCD"},
        {"modbus", "read_only", "true", "yes"},
        {"log", "level", "info", "INFO"},
        {"can", "base_id", "0x500", "1280"},
        {"robot", "connect_timeout_ms", "3000", "03000"},
        {"rtu", "rights", "power, heartbeat", "heartbeat,power"},
        {"rtu", "parity", "even", "EVEN"},
    };
    static const char *const changed[][4] = {
        {"robot", "tls_fingerprint", "",
         "abcdef0123456789abcdef0123456789abcdef0123456789abcdef0123456789"},
        {"modbus", "write_allow", "10.0.0.1", "10.0.0.2"},
        {"modbus", "write_allow", "none", ""},
        {"modbus", "unit_id", "any", "0"},
        {"modbus", "idle_timeout_ms", "60000", "0"},
        {"tls", "client_ca", "/etc/a.crt", "/etc/b.crt"},
        /* Each rights key compares its own mask, not the other's. */
        {"rtu", "rights", "read", "power"},
        {"tls", "default_rights", "read", "write"},
    };
    (void)state;
    for (size_t n = 0; n < sizeof(same) / sizeof(same[0]) + sizeof(changed) / sizeof(changed[0]);
         n++) {
        bool is_same = n < sizeof(same) / sizeof(same[0]);
        const char *const *row = is_same ? same[n] : changed[n - sizeof(same) / sizeof(same[0])];
        struct gw_config a, b;
        char why[256];

        config_defaults(&a);
        config_defaults(&b);
        if (config_set(&a, row[0], row[1], row[2], why, sizeof(why)) != 0 ||
            config_set(&b, row[0], row[1], row[3], why, sizeof(why)) != 0)
            fail_msg("[%s] %s: %s", row[0], row[1], why);
        size_t at = key_index(row[0], row[1]);
        for (size_t i = 0; i < config_key_count(); i++) {
            bool expect = i == at ? is_same : true;
            if (config_key_equal(&a, &b, i) != expect)
                fail_msg("[%s] %s = '%s' / '%s': key [%s] %s compared %s", row[0], row[1],
                         row[2], row[3], config_key_section(i), config_key_name(i),
                         expect ? "different" : "equal");
        }
    }
}

/* [roles] takes role names in any language; what it refuses, it names. */
static void role_names_are_utf8(void **state)
{
    struct gw_config c;
    (void)state;

    expect_loaded("[roles]\nop\xC3\xA9rateur = read\n\xE6\x93\x8D\xE4\xBD\x9C\xE5\x91\x98 = write\n",
                  &c);
    assert_int_equal(c.role_count, 2);
    assert_string_equal(c.roles[0].name, "op\xC3\xA9rateur");
    bool listed = false;
    assert_int_equal(config_role_rights(&c, "op\xC3\xA9rateur", true, &listed), c.roles[0].rights);
    assert_true(listed);
    const char bad_utf8[] = "[roles]\nop\xE9" "rateur = read\n";
    expect_refused(bad_utf8, sizeof(bad_utf8) - 1, "not valid UTF-8");
    const char nbsp[] = "[roles]\nop\xC2\xA0" "erator = read\n";
    expect_refused(nbsp, sizeof(nbsp) - 1, "has a space or a control character");
    const char *long_name = "[roles]\n"
                            "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa = read\n";
    expect_refused(long_name, strlen(long_name), "at most 63 bytes");
}

/*
 * What a reload names as waiting for a restart (the summary line and the
 * status line): the changed keys that are not live, in table order; a live
 * key that changed is not among them; none changed, nothing named; a list
 * longer than the room ends with "...".
 */
static void reload_names_the_keys_that_need_a_restart(void **state)
{
    struct gw_config running, next;
    char text[CONFIG_RELOAD_KEYS_TEXT], why[256];

    (void)state;
    config_defaults(&running);
    config_defaults(&next);
    assert_int_equal(config_reload_restart_keys(&running, &next, text, sizeof(text)), 0);
    assert_string_equal(text, "");
    assert_int_equal(config_set(&next, "modbus", "port", "1502", why, sizeof(why)), 0);
    assert_int_equal(config_set(&next, "robot", "host", "10.0.0.7", why, sizeof(why)), 0);
    assert_int_equal(config_set(&next, "modbus", "idle_timeout_ms", "500", why, sizeof(why)), 0);
    assert_int_equal(config_reload_restart_keys(&running, &next, text, sizeof(text)), 2);
    assert_string_equal(text, "[robot] host, [modbus] port");
    /* Room for the first name and ", ..." only. */
    assert_int_equal(config_reload_restart_keys(&running, &next, text, 20), 2);
    assert_string_equal(text, "[robot] host, ...");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(defaults),
        cmocka_unit_test(owner_and_require_heartbeat),
        cmocka_unit_test(file_overrides_defaults),
        cmocka_unit_test(bad_values_name_key_and_line),
        cmocka_unit_test(missing_file),
        cmocka_unit_test(directory_is_refused),
        cmocka_unit_test(unreadable_path_is_not_missing),
        cmocka_unit_test(modbus_bind_must_be_an_ip_address),
        cmocka_unit_test(robot_host_is_an_address_or_a_host_name),
        cmocka_unit_test(long_line_names_key_and_line),
        cmocka_unit_test(unterminated_section_is_named),
        cmocka_unit_test(nul_byte_is_refused),
        cmocka_unit_test(duplicate_key_names_both_lines),
        cmocka_unit_test(first_error_is_reported),
        cmocka_unit_test(indented_continuation_is_refused),
        cmocka_unit_test(key_before_any_section),
        cmocka_unit_test(max_document_bytes_at_its_limits),
        cmocka_unit_test(rules_between_keys),
        cmocka_unit_test(rtu_keys),
        cmocka_unit_test(keys_compare_by_type),
        cmocka_unit_test(reload_names_the_keys_that_need_a_restart),
        cmocka_unit_test(role_names_are_utf8),
        cmocka_unit_test(shipped_config_is_valid),
    };
    return cmocka_run_group_tests_name("config", tests, NULL, NULL);
}
