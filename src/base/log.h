/* SPDX-License-Identifier: MIT */
/*
 * log.h - the one logger of jakagw and jakasim.
 *
 * Lines go to stderr with a "<N>" syslog priority prefix, which journald
 * turns into the entry's level. There are no log files. log_debug() costs a
 * branch when debugging is off but keeps printf format checking.
 *
 * Outside text is data, never markup: a configuration value, a flag, a text
 * the robot sends or a PLC writes reaches the log only through here, and
 * every line is escaped as a whole (log_escape), so no caller can forget
 * and no peer can end a line, start a forged journal entry or repaint a
 * terminal. Valid UTF-8 (Chinese program names, controller messages) is
 * kept as it is.
 */
#ifndef JAKAGW_LOG_H
#define JAKAGW_LOG_H

#include <stdbool.h>
#include <stddef.h>
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

/*
 * Prints one line at 'level', escaped; a trailing newline is added. A line
 * longer than LOG_LINE_MAX bytes before escaping is cut, at a character
 * boundary, and ends with "...".
 */
void log_print(enum log_level level, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/*
 * Prints one line to stderr without a priority prefix, escaped as
 * log_print() does: the command line's errors ("jakagw: ..."), read by a
 * person at a terminal rather than by journald.
 */
void log_plain(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

#define LOG_LINE_MAX 1024

/*
 * Writes 'in' (size bytes) to 'out' as text that is one line and cannot
 * move a terminal's cursor:
 * - C0 control bytes (0x00-0x1F, so also tab, CR and LF) and DEL become
 *   "\xNN" (lower-case hex), and a backslash becomes "\\", so the escaped
 *   form reads back unambiguously;
 * - C1 controls, which are valid UTF-8 (U+0080-U+009F, for example CSI
 *   U+009B), become "\u00NN";
 * - a byte that does not start a valid UTF-8 sequence (a stray
 *   continuation byte, an overlong form, a surrogate, beyond U+10FFFF, a
 *   sequence cut short) becomes "\xNN", and scanning goes on with the next
 *   byte;
 * - everything else, all valid UTF-8 included, is copied as it is.
 * 'out' always ends with NUL (size_out > 0); an escape that does not fit
 * whole is left out, never cut. Returns the length the whole escaped text
 * needs, not counting the NUL (as snprintf does); at most 6 * size.
 */
size_t log_escape(char *out, size_t size_out, const char *in, size_t size);

/*
 * The length of the well-formed UTF-8 sequence of 2 to 4 bytes at 'p', of
 * which 'left' bytes may be read (RFC 3629: no overlong forms, no
 * surrogates, nothing above U+10FFFF), or 0.
 */
size_t utf8_sequence(const unsigned char *p, size_t left);

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
