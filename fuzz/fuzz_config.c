/* SPDX-License-Identifier: MIT */
/*
 * fuzz_config.c - libFuzzer target: the configuration parser (config.c).
 *
 * The first byte picks the path and the padding:
 * - bit 0 clear: the rest is a configuration file for config_load(). An
 *   escape, 0xFF N C, stands for the byte C repeated 8 * (N + 1) times, so
 *   short inputs make lines longer than libinih's 200-byte line buffer
 *   (and values longer than every key's limit). Bits 1-2 pad the file
 *   towards the 1 MiB cap: not at all, one long comment line, or many
 *   short comment lines, ending 0-255 bytes (the second byte) below or
 *   above the cap.
 * - bit 0 set: the rest is "section NUL key NUL value NUL" triples for
 *   config_set() (the command line's path), with the same escape.
 * Rules: config_load() returns 0 or one of the errors config.h lists, and
 * its message is a terminated line; a file above the cap is refused with
 * -EFBIG and one at or below it never is; every string member stays
 * terminated within its buffer. A file that loads and validates prints
 * (config_print, as --check-config does) a file that loads again into the
 * same configuration.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "config.h"
#include "fuzz_util.h"
#include "log.h"


#define CAP (1024 * 1024) /* config.c's CONFIG_MAX_FILE_BYTES */
#define TEXT_MAX (CAP + 65536) /* expansions stop here: past the cap is enough */

static char *text;      /* the expanded input */
static size_t text_size;
static int file_fd = -1;
static char file_path[64];

/* Expands the 0xFF N C escapes of 'in' into 'text'. */
static void expand(const uint8_t *in, size_t size)
{
    text_size = 0;
    for (size_t i = 0; i < size; i++) {
        if (text_size + 2048 > TEXT_MAX)
            break;
        if (in[i] == 0xFF && i + 2 < size) {
            size_t n = 8 * ((size_t)in[i + 1] + 1);
            memset(text + text_size, in[i + 2], n);
            text_size += n;
            i += 2;
        } else {
            text[text_size++] = (char)in[i];
        }
    }
}

static void write_file(const char *data, size_t size)
{
    if (ftruncate(file_fd, 0) < 0 || pwrite(file_fd, data, size, 0) != (ssize_t)size)
        abort();
}

static void check_strings(const struct gw_config *cfg)
{
    FUZZ_REQUIRE(memchr(cfg->robot_host, '\0', sizeof(cfg->robot_host)), "robot_host");
    FUZZ_REQUIRE(memchr(cfg->modbus_bind, '\0', sizeof(cfg->modbus_bind)), "modbus_bind");
    FUZZ_REQUIRE(memchr(cfg->write_allow, '\0', sizeof(cfg->write_allow)), "write_allow");
    FUZZ_REQUIRE(memchr(cfg->can_interface, '\0', sizeof(cfg->can_interface)), "can_interface");
}

static int load(struct gw_config *cfg, char *why, size_t why_size)
{
    memset(why, 'X', why_size);
    why[why_size - 1] = 'X';
    config_defaults(cfg);
    int rc = config_load(cfg, file_path, why, why_size);
    FUZZ_REQUIRE(rc == 0 || rc == -EINVAL || rc == -EFBIG || rc == -ENOMEM,
            "config_load returned %d", rc);
    if (rc)
        FUZZ_REQUIRE(memchr(why, '\0', why_size), "the error message is not terminated");
    check_strings(cfg);
    return rc;
}

/* What --check-config prints for 'cfg'. */
static char *print(const struct gw_config *cfg, size_t *size)
{
    char *out = NULL;
    FILE *f = open_memstream(&out, size);
    if (!f)
        abort();
    config_print(cfg, f);
    fclose(f);
    return out;
}

static void fuzz_file(uint8_t flags, uint8_t delta)
{
    struct gw_config cfg, again;
    char why[512];
    size_t body = text_size;
    int pad = (flags >> 1) & 3;

    if (pad && body < CAP) {
        /* The file's end: 'delta' below the cap, or above it (bit 3). */
        size_t target = flags & 8 ? (size_t)CAP + 1 + delta : (size_t)CAP - delta;
        size_t at = body;
        if (target > at + 2) {
            size_t fill = target - at;
            text[at++] = '\n';
            fill--;
            if (pad == 1) { /* one comment line */
                text[at++] = '#';
                memset(text + at, 'c', fill - 1);
            } else { /* comment lines of 64 bytes */
                for (size_t i = 0; i < fill; i++)
                    text[at + i] = i % 64 == 0 ? ';' : i % 64 == 63 ? '\n' : ' ';
            }
            text_size = target;
        }
    }
    write_file(text, text_size);
    int rc = load(&cfg, why, sizeof(why));
    if (text_size > CAP)
        FUZZ_REQUIRE(rc == -EFBIG, "a %zu-byte file was not refused as too large (%d)",
                text_size, rc);
    else
        FUZZ_REQUIRE(rc != -EFBIG, "a %zu-byte file was refused as too large", text_size);
    if (rc || config_validate(&cfg, why, sizeof(why)))
        return;
    /* The printed configuration loads back into the same one. */
    size_t printed_size;
    char *printed = print(&cfg, &printed_size);
    write_file(printed, printed_size);
    rc = load(&again, why, sizeof(why));
    FUZZ_REQUIRE(rc == 0, "the printed configuration does not load: %s\n%s", why, printed);
    size_t reprinted_size;
    char *reprinted = print(&again, &reprinted_size);
    FUZZ_REQUIRE(printed_size == reprinted_size && memcmp(printed, reprinted, printed_size) == 0,
            "the printed configuration loads as another:\n%s\n----\n%s", printed, reprinted);
    free(printed);
    free(reprinted);
}

static void fuzz_set(void)
{
    struct gw_config cfg;
    char why[256];
    const char *p = text, *end = text + text_size;

    config_defaults(&cfg);
    for (unsigned i = 0; i < 64 && p < end; i++) {
        const char *field[3];
        for (int k = 0; k < 3; k++) {
            const char *nul = memchr(p, '\0', (size_t)(end - p));
            if (!nul)
                return;
            field[k] = p;
            p = nul + 1;
        }
        memset(why, 'X', sizeof(why));
        int rc = config_set(&cfg, field[0], field[1], field[2], why, sizeof(why));
        FUZZ_REQUIRE(rc == 0 || rc == -EINVAL, "config_set returned %d", rc);
        if (rc)
            FUZZ_REQUIRE(memchr(why, '\0', sizeof(why)), "the error message is not terminated");
        check_strings(&cfg);
    }
    config_validate(&cfg, why, sizeof(why));
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (file_fd < 0) {
        log_set_level((enum log_level)0);
        /* Room for the largest expansion and for padding past the cap. */
        text = malloc(TEXT_MAX + 1);
        file_fd = memfd_create("jakagw.conf", 0);
        if (!text || file_fd < 0)
            abort();
        snprintf(file_path, sizeof(file_path), "/proc/self/fd/%d", file_fd);
    }
    if (size < 2 || size > 16384)
        return 0;
    expand(data + 2, size - 2);
    if (data[0] & 1) {
        text[text_size++] = '\0';
        fuzz_set();
    } else {
        fuzz_file(data[0], data[1]);
    }
    return 0;
}
