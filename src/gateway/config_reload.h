/* SPDX-License-Identifier: MIT */
/*
 * config_reload.h - what a configuration reload (SIGHUP) changes in a
 * running gateway.
 *
 * The new configuration has been read and validated in full before it gets
 * here; a file with any error never reaches these functions, and the
 * running configuration stays in force. Keys are compared one by one,
 * through the configuration's key table, each as its type has it (a number
 * as a number, write_allow as its addresses, default_rights as its rights,
 * a fingerprint as its bytes: config_key_equal), and logged as
 * --check-config prints them. A key in the live table below
 * (config_reload.c) takes effect at once: the log level, the Modbus
 * limits and timeouts, the robot links' timeouts and backoff. Every other
 * key (addresses, ports, the robot host, the register word order, the
 * document size limit, the CAN mirror) keeps its running value until a
 * restart, and each one that differs gets one log line saying so. A key
 * added to the configuration needs a restart until it is added to the
 * live table.
 */
#ifndef JAKAGW_CONFIG_RELOAD_H
#define JAKAGW_CONFIG_RELOAD_H

#include <stdbool.h>
#include <stdio.h>

#include "config.h"
#include "gateway.h"

/* Does a changed value of [section] key take effect on reload? */
bool config_reload_is_live(const char *section, const char *key);

/*
 * Prints every configuration key, one per line, tab-separated: section,
 * key, default value, and "live" or "restart" (what a reload does with a
 * changed value). For the man page and its test. Returns 0 or -errno.
 */
int config_reload_print_keys(FILE *out);

/* Room for the names of the keys that wait for a restart. */
#define CONFIG_RELOAD_KEYS_TEXT 200

struct config_reload_result {
    unsigned applied; /* live keys that changed and took effect */
    unsigned restart; /* changed keys that keep their value until a restart */
    /* Those keys, "[robot] host, [modbus] port", for the summary line and
     * the service's status line; "" when none. */
    char restart_keys[CONFIG_RELOAD_KEYS_TEXT];
};

/*
 * Writes into 'out' the names of the keys that differ between 'running'
 * and 'next' and need a restart, "[section] key" separated by ", ", in
 * the order of the key table; a list longer than 'size' ends with "...".
 * Returns how many keys there are (all of them, even those cut off).
 */
unsigned config_reload_restart_keys(const struct gw_config *running,
                                    const struct gw_config *next, char *out, size_t size);

/*
 * Applies 'next', a configuration already validated, to the running
 * gateway 'gw': the live keys that differ take effect and are logged; the
 * others that differ are logged as needing a restart and keep their value.
 * Returns 0.
 */
int config_reload_apply(struct gateway *gw, const struct gw_config *next,
                        struct config_reload_result *result);

#endif
