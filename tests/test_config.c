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

#include "config.h"

static char path[64];

static void write_conf(const char *text)
{
    snprintf(path, sizeof(path), "/tmp/jakagw-test-%d.conf", (int)getpid());
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs(text, f);
    fclose(f);
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

static void shipped_config_is_valid(void **state)
{
    (void)state;
    struct gw_config c, d;
    char why[256];
    config_defaults(&c);
    config_defaults(&d);
    assert_int_equal(config_load(&c, CONFIG_FILE, why, sizeof(why)), 0);
    /* The shipped file documents the defaults: loading it changes nothing. */
    assert_memory_equal(&c, &d, sizeof(c));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(defaults),
        cmocka_unit_test(file_overrides_defaults),
        cmocka_unit_test(bad_values_name_key_and_line),
        cmocka_unit_test(missing_file),
        cmocka_unit_test(rules_between_keys),
        cmocka_unit_test(shipped_config_is_valid),
    };
    return cmocka_run_group_tests_name("config", tests, NULL, NULL);
}
