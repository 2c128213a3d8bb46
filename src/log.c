/* SPDX-License-Identifier: MIT */
/* log.c - see log.h. */
#include "log.h"

#include <stdarg.h>
#include <stdio.h>

static enum log_level max_level = LOG_LEVEL_INFO;

void log_set_level(enum log_level level) { max_level = level; }

bool log_enabled(enum log_level level) { return level <= max_level; }

void log_print(enum log_level level, const char *fmt, ...)
{
    char line[1024];
    va_list ap;

    if (!log_enabled(level))
        return;
    va_start(ap, fmt);
    vsnprintf(line, sizeof(line), fmt, ap);
    va_end(ap);
    /* One fprintf per line so that lines from one process never interleave. */
    fprintf(stderr, "<%d>%s\n", (int)level, line);
}

bool log_ratelimit_pass(struct log_ratelimit *rl, uint64_t now_ms,
                        uint64_t *suppressed)
{
    if (rl->primed && now_ms - rl->last_ms < rl->interval_ms) {
        rl->suppressed++;
        return false;
    }
    *suppressed = rl->suppressed;
    rl->suppressed = 0;
    rl->last_ms = now_ms;
    rl->primed = true;
    return true;
}
