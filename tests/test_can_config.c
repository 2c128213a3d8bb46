/* SPDX-License-Identifier: MIT */
/* test_can_config.c - the [can] configuration keys and their rules. */
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

#include "can_map.h"
#include "config.h"

static int set(struct gw_config *c, const char *key, const char *value, char *why)
{
    return config_set(c, "can", key, value, why, 256);
}

static void expect_refused(const char *key, const char *value, const char *reason)
{
    struct gw_config c;
    char why[256] = "";

    config_defaults(&c);
    if (set(&c, key, value, why) != -EINVAL)
        fail_msg("%s = '%s' was accepted", key, value);
    if (!strstr(why, reason))
        fail_msg("%s = '%s': '%s' lacks '%s'", key, value, why, reason);
}

static void defaults_are_off(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];

    config_defaults(&c);
    assert_false(c.can_enabled);
    assert_string_equal(c.can_interface, "");
    assert_int_equal(c.can_base_id, CAN_MAP_DEFAULT_BASE_ID);
    assert_false(c.can_extended_ids);
    assert_int_equal(c.can_period_ms, 100);
    assert_int_equal(c.can_groups, CAN_GROUPS_ALL);
    assert_int_equal(config_validate(&c, why, sizeof(why)), 0);
}

static void keys_are_read(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];

    config_defaults(&c);
    assert_int_equal(set(&c, "enabled", "yes", why), 0);
    assert_true(c.can_enabled);
    assert_int_equal(set(&c, "enabled", "Off", why), 0);
    assert_false(c.can_enabled);
    assert_int_equal(set(&c, "extended_ids", "1", why), 0);
    assert_true(c.can_extended_ids);
    assert_int_equal(set(&c, "interface", "can0", why), 0);
    assert_string_equal(c.can_interface, "can0");
    assert_int_equal(set(&c, "interface", "", why), 0);
    assert_string_equal(c.can_interface, "");
    assert_int_equal(set(&c, "interface", "abcdefghijklmno", why), 0); /* 15 */
    assert_int_equal(set(&c, "base_id", "0x18ff0000", why), 0);
    assert_int_equal(c.can_base_id, 0x18FF0000);
    assert_int_equal(set(&c, "base_id", "256", why), 0);
    assert_int_equal(c.can_base_id, 256);
    assert_int_equal(set(&c, "period_ms", "5", why), 0);
    assert_int_equal(set(&c, "period_ms", "10000", why), 0);
    assert_int_equal(set(&c, "frames", "health,tcp", why), 0);
    assert_int_equal(c.can_groups, 1u << CAN_GROUP_health | 1u << CAN_GROUP_tcp);
}

static void bad_values_say_why(void **state)
{
    (void)state;
    expect_refused("enabled", "maybe", "'maybe' must be true or false");
    expect_refused("interface", "abcdefghijklmnop", "must be at most 15 characters");
    expect_refused("interface", "can 0", "not a network interface name");
    expect_refused("interface", "can/0", "not a network interface name");
    expect_refused("interface", "..", "not a network interface name");
    expect_refused("base_id", "0x", "not a CAN identifier");
    expect_refused("base_id", "-1", "not a CAN identifier");
    expect_refused("base_id", "0x500g", "not a CAN identifier");
    expect_refused("base_id", "0x20000000", "out of range 0..0x1FFFFFFF");
    expect_refused("period_ms", "4", "out of range 5..10000");
    expect_refused("period_ms", "10001", "out of range 5..10000");
    expect_refused("frames", "", "lists no frame group");
    expect_refused("frames", "state,bogus", "'bogus' is not a frame group");
    expect_refused("bitrate", "500000", "unknown key");
}

static void rules_between_keys(void **state)
{
    (void)state;
    struct gw_config c;
    char why[256];

    config_defaults(&c);
    c.can_enabled = true;
    assert_int_equal(config_validate(&c, why, sizeof(why)), -EINVAL);
    assert_string_equal(why, "[can] enabled: true needs an interface");
    snprintf(c.can_interface, sizeof(c.can_interface), "vcan0");
    assert_int_equal(config_validate(&c, why, sizeof(why)), 0);
    c.can_base_id = CAN_MAX_STD_ID - can_map_max_offset();
    assert_int_equal(config_validate(&c, why, sizeof(why)), 0);
    c.can_base_id++;
    assert_int_equal(config_validate(&c, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "[can] base_id: 0x7F8 leaves no room"));
    c.can_extended_ids = true;
    assert_int_equal(config_validate(&c, why, sizeof(why)), 0);
    c.can_base_id = CAN_MAX_EXT_ID;
    assert_int_equal(config_validate(&c, why, sizeof(why)), -EINVAL);
    /* Not enabled: nothing of [can] is in force, nothing is refused. */
    c.can_enabled = false;
    assert_int_equal(config_validate(&c, why, sizeof(why)), 0);
}

static void printed_as_read(void **state)
{
    (void)state;
    struct gw_config c, again;
    char why[256], *text = NULL, path[64];
    size_t size = 0;
    FILE *mem;

    config_defaults(&c);
    assert_int_equal(set(&c, "enabled", "true", why), 0);
    assert_int_equal(set(&c, "interface", "vcan0", why), 0);
    assert_int_equal(set(&c, "base_id", "0x123", why), 0);
    assert_int_equal(set(&c, "frames", "state joints", why), 0);
    mem = open_memstream(&text, &size);
    config_print(&c, mem);
    fclose(mem);
    assert_non_null(strstr(text, "[can]\nenabled = true\ninterface = vcan0\nbase_id = 0x123\n"
                                 "extended_ids = false\nperiod_ms = 100\n"
                                 "frames = state,joints\n"));
    /* What --check-config prints reads back to the same settings. */
    snprintf(path, sizeof(path), "/tmp/jakagw-can-config-%d.conf", (int)getpid());
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs(text, f);
    fclose(f);
    config_defaults(&again);
    assert_int_equal(config_load(&again, path, why, sizeof(why)), 0);
    remove(path);
    /* The printed file names the robot; whether 'c' did is not printed. */
    assert_true(again.robot_named);
    again.robot_named = c.robot_named;
    assert_memory_equal(&again, &c, sizeof(c));
    free(text);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(defaults_are_off),
        cmocka_unit_test(keys_are_read),
        cmocka_unit_test(bad_values_say_why),
        cmocka_unit_test(rules_between_keys),
        cmocka_unit_test(printed_as_read),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
