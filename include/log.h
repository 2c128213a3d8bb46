/* SPDX-License-Identifier: MIT */
/*
 * log.h - the one logger of jakagw and jakasim.
 *
 * Lines go to stderr with a "<N>" syslog priority prefix, which journald
 * turns into the entry's level. There are no log files. log_debug() costs a
 * branch when debugging is off but keeps printf format checking.
 */
#ifndef JAKAGW_LOG_H
#define JAKAGW_LOG_H

#include <stdbool.h>
#include <stdint.h>

enum log_level {
    LOG_LEVEL_ERR = 3,
    LOG_LEVEL_WARNING = 4,
    LOG_LEVEL_NOTICE = 5,
    LOG_LEVEL_INFO = 6,
    LOG_LEVEL_DEBUG = 7,
};

/* Sets the most verbose level printed (default LOG_LEVEL_INFO). */
void log_set_level(enum log_level level);
bool log_enabled(enum log_level level);

/* Prints one line at 'level'; a trailing newline is added. */
void log_print(enum log_level level, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

#define log_err(...) log_print(LOG_LEVEL_ERR, __VA_ARGS__)
#define log_warn(...) log_print(LOG_LEVEL_WARNING, __VA_ARGS__)
#define log_notice(...) log_print(LOG_LEVEL_NOTICE, __VA_ARGS__)
#define log_info(...) log_print(LOG_LEVEL_INFO, __VA_ARGS__)
#define log_debug(...)                                                         \
    do {                                                                       \
        if (log_enabled(LOG_LEVEL_DEBUG))                                      \
            log_print(LOG_LEVEL_DEBUG, __VA_ARGS__);                           \
    } while (0)

/*
 * A rate limiter for messages a remote peer can trigger: at most one line
 * per 'interval_ms'; the lines held back are counted and reported with the
 * next line that passes.
 */
struct log_ratelimit {
    uint64_t interval_ms;
    uint64_t last_ms;
    uint64_t suppressed;
    bool primed;
};

/*
 * Returns true when a line may be printed at 'now_ms'; then *suppressed is
 * the number of lines held back since the last one printed.
 */
bool log_ratelimit_pass(struct log_ratelimit *rl, uint64_t now_ms,
                        uint64_t *suppressed);

#endif
