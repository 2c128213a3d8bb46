/* SPDX-License-Identifier: MIT */
#include "unit_exec.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <systemd/sd-bus.h>

/* systemd's own socket, as systemctl uses it as root: it answers with no
 * D-Bus daemon running (a minimal image has none). */
#define SYSTEMD_PRIVATE "unix:path=/run/systemd/private"

static int connect_systemd(sd_bus **bus)
{
    int r;

    if (geteuid() == 0) {
        r = sd_bus_new(bus);
        if (r < 0)
            return r;
        r = sd_bus_set_address(*bus, SYSTEMD_PRIVATE);
        if (r >= 0)
            r = sd_bus_start(*bus);
        if (r >= 0)
            return 0;
        *bus = sd_bus_flush_close_unref(*bus);
    }
    return sd_bus_open_system(bus);
}

/* The first command of an ExecStart= property, a(sasbttttuii): its path,
 * then its argv (the rest: flags and times, not needed). */
static int read_first_command(sd_bus_message *reply, char ***argv)
{
    const char *path;
    int r = sd_bus_message_enter_container(reply, 'a', "(sasbttttuii)");
    if (r < 0)
        return r;
    r = sd_bus_message_enter_container(reply, 'r', "sasbttttuii");
    if (r <= 0)
        return r < 0 ? r : -ENOENT; /* no ExecStart= at all */
    r = sd_bus_message_read(reply, "s", &path);
    if (r < 0)
        return r;
    r = sd_bus_message_read_strv(reply, argv);
    if (r < 0)
        return r;
    return *argv && (*argv)[0] ? 0 : -ENOENT;
}

int unit_exec_start(const char *unit, char ***argv, char *why, size_t why_size)
{
    sd_bus *bus = NULL;
    sd_bus_message *reply = NULL;
    sd_bus_error error = SD_BUS_ERROR_NULL;
    char *object = NULL;
    const char *step = "connecting to systemd";
    int r;

    *argv = NULL;
    r = connect_systemd(&bus);
    if (r >= 0) {
        step = "the unit's object path";
        r = sd_bus_path_encode("/org/freedesktop/systemd1/unit", unit, &object);
    }
    if (r >= 0) {
        step = "reading ExecStart";
        r = sd_bus_get_property(bus, "org.freedesktop.systemd1", object,
                                "org.freedesktop.systemd1.Service", "ExecStart", &error, &reply,
                                "a(sasbttttuii)");
    }
    if (r >= 0) {
        step = "its first command";
        r = read_first_command(reply, argv);
    }
    if (r < 0) {
        snprintf(why, why_size, "%s: %s", step,
                 sd_bus_error_is_set(&error) ? error.message : strerror(-r));
        unit_exec_free(*argv);
        *argv = NULL;
    }
    sd_bus_error_free(&error);
    sd_bus_message_unref(reply);
    sd_bus_flush_close_unref(bus);
    free(object);
    return r < 0 ? r : 0;
}

void unit_exec_free(char **argv)
{
    if (!argv)
        return;
    for (char **w = argv; *w; w++)
        free(*w);
    free(argv);
}
