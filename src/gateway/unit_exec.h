/* SPDX-License-Identifier: MIT */
/*
 * unit_exec.h - the command line systemd runs a unit's service with: the
 * first ExecStart= of the unit as systemd has it loaded, drop-ins included
 * (a 'systemctl edit' that adds a flag or names another file), read over
 * D-Bus from systemd itself (its private socket when root, else the system
 * bus). The units' start condition (jakagw --start-condition) checks that
 * command line with the gateway's own parser before each start, so the
 * question costs one D-Bus call, not a systemctl process.
 */
#ifndef JAKAGW_UNIT_EXEC_H
#define JAKAGW_UNIT_EXEC_H

#include <stddef.h>

/* The words of 'unit's first ExecStart= into *argv (NULL-terminated, at
 * least one word; free with unit_exec_free). Returns 0, or a negative
 * errno (no systemd to ask, no such unit, no ExecStart=); 'why' then says
 * what failed. */
int unit_exec_start(const char *unit, char ***argv, char *why, size_t why_size);
void unit_exec_free(char **argv);

#endif
