/* SPDX-License-Identifier: MIT */
/* cmd_json.c - see cmd_json.h. */
#include "cmd_json.h"

#include <errno.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- numbers, as cJSON prints them ---- */

/*
 * A decimal number: significant digits without leading or trailing zeros,
 * and the power of ten of the first one (123.4: "1234", 2).
 */
struct decimal {
    bool negative;
    char digits[24];
    int count; /* 0: the number is zero */
    int exponent;
};

static size_t write_unsigned(char *out, uint64_t v)
{
    char tmp[24];
    size_t n = 0, i;
    do {
        tmp[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    for (i = 0; i < n; i++)
        out[i] = tmp[n - 1 - i];
    return n;
}

static size_t write_integer(char *out, long long v)
{
    if (v < 0) {
        out[0] = '-';
        return 1 + write_unsigned(out + 1, (uint64_t)0 - (uint64_t)v);
    }
    return write_unsigned(out, (uint64_t)v);
}

/* Drops trailing zeros; a number with no digit left is zero. */
static void trim_decimal(struct decimal *d)
{
    while (d->count > 0 && d->digits[d->count - 1] == '0')
        d->count--;
}

/* k x 10^-places as a decimal (k != 0, |k| < 10^17). */
static void decimal_of_scaled(struct decimal *d, long long k, int places)
{
    d->negative = k < 0;
    d->count = (int)write_unsigned(d->digits, k < 0 ? (uint64_t)0 - (uint64_t)k : (uint64_t)k);
    d->exponent = d->count - 1 - places;
    trim_decimal(d);
}

/* The decimal printf's %g wrote into 't' ("-1.5e+08", "0.00012", "42"). */
static void decimal_of_text(struct decimal *d, const char *t)
{
    char raw[40];
    int n = 0, before_point = -1, exp = 0, first = -1;

    d->negative = *t == '-';
    if (*t == '-' || *t == '+')
        t++;
    for (; (*t >= '0' && *t <= '9') || *t == '.'; t++) {
        if (*t == '.')
            before_point = n;
        else if (n < (int)sizeof(raw))
            raw[n++] = *t;
    }
    if (before_point < 0)
        before_point = n;
    if (*t == 'e' || *t == 'E')
        exp = atoi(t + 1);
    for (int i = 0; i < n && first < 0; i++)
        if (raw[i] != '0')
            first = i;
    d->count = 0;
    if (first < 0)
        return;
    for (int i = first; i < n && d->count < (int)sizeof(d->digits); i++)
        d->digits[d->count++] = raw[i];
    d->exponent = before_point - 1 - first + exp;
    trim_decimal(d);
}

/* printf's "%1.15g" of a decimal of at most 15 significant digits. */
static size_t write_g15(char *out, const struct decimal *d)
{
    size_t n = 0;
    int x = d->exponent;

    if (d->negative)
        out[n++] = '-';
    if (x < -4 || x >= 15) {
        out[n++] = d->digits[0];
        if (d->count > 1) {
            out[n++] = '.';
            memcpy(out + n, d->digits + 1, (size_t)d->count - 1);
            n += (size_t)d->count - 1;
        }
        out[n++] = 'e';
        out[n++] = x < 0 ? '-' : '+';
        unsigned e = (unsigned)(x < 0 ? -x : x);
        if (e < 10)
            out[n++] = '0';
        n += write_unsigned(out + n, e);
        return n;
    }
    if (x < 0) {
        out[n++] = '0';
        out[n++] = '.';
        for (int i = 0; i < -x - 1; i++)
            out[n++] = '0';
        memcpy(out + n, d->digits, (size_t)d->count);
        return n + (size_t)d->count;
    }
    for (int i = 0; i <= x; i++)
        out[n++] = i < d->count ? d->digits[i] : '0';
    if (d->count > x + 1) {
        out[n++] = '.';
        memcpy(out + n, d->digits + x + 1, (size_t)(d->count - x - 1));
        n += (size_t)(d->count - x - 1);
    }
    return n;
}

/* The integer a decimal stands for, when it is one within int's range. */
static bool int_of_decimal(const struct decimal *d, long long *v)
{
    if (d->count == 0) {
        *v = 0;
        return true;
    }
    if (d->exponent < d->count - 1 || d->exponent > 10)
        return false;
    long long r = 0;
    for (int i = 0; i <= d->exponent; i++)
        r = r * 10 + (i < d->count ? d->digits[i] - '0' : 0);
    if (d->negative)
        r = -r;
    if (r < INT_MIN || r > INT_MAX)
        return false;
    *v = r;
    return true;
}

/* cJSON's test for an integer: the value equals its int (saturated). */
static bool is_cjson_int(double v)
{
    int i = v >= INT_MAX ? INT_MAX : v <= (double)INT_MIN ? INT_MIN : (int)v;
    return v == (double)i;
}

/*
 * A value with at most 9 decimal places and 15 digits: k x 10^-p, the
 * shortest. Its %1.15g is that decimal, since a decimal of 15 digits or
 * fewer reads back as the same double (DBL_DIG).
 */
static bool short_decimal(double v, struct decimal *d)
{
    static const double tens[] = {1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9};

    for (int p = 0; p < 9; p++) {
        double r = v * tens[p];
        double k = nearbyint(r);
        if (fabs(k) >= 1e15)
            return false;
        if (r == k && k / tens[p] == v) {
            decimal_of_scaled(d, (long long)k, p + 1);
            return true;
        }
    }
    return false;
}

/* cJSON's own way, for a number with no short decimal form. */
static size_t write_as_cjson(char *out, double v)
{
    double back = 0;
    int n = snprintf(out, 32, "%1.15g", v);
    if (sscanf(out, "%lg", &back) != 1 ||
        !(fabs(back - v) <= fmax(fabs(back), fabs(v)) * DBL_EPSILON))
        n = snprintf(out, 32, "%1.17g", v);
    return (size_t)n;
}

size_t cmd_json_number(char *out, double value, bool from_float)
{
    struct decimal d;
    long long i;

    if (isnan(value) || isinf(value)) {
        memcpy(out, "null", 4);
        return 4;
    }
    if (value == 0) {
        /* cJSON 1.7.15 prints every number with %g: negative zero as -0. */
        size_t n = signbit(value) ? 1 : 0;
        memcpy(out, "-0", 2);
        if (!n)
            out[0] = '0';
        return n + 1;
    }
    if (from_float) {
        /* The float's 7 digits (it holds no more), as the number sent. */
        char text[32];
        snprintf(text, sizeof(text), "%.7g", value);
        /* Below the doubles' normal range (no float is), 7 digits do not
         * name one double: cJSON's way. */
        if (fabs(value) < DBL_MIN)
            return write_as_cjson(out, strtod(text, NULL));
        decimal_of_text(&d, text);
        if (d.count == 0)
            return cmd_json_number(out, d.negative ? -0.0 : 0.0, false);
        if (int_of_decimal(&d, &i))
            return write_integer(out, i);
        return write_g15(out, &d);
    }
    if (is_cjson_int(value))
        return write_integer(out, (long long)value);
    if (short_decimal(value, &d))
        return write_g15(out, &d);
    return write_as_cjson(out, value);
}

/* ---- strings, as cJSON escapes them ---- */

/* Writes 's' quoted and escaped into out (room: 6 bytes a byte + 2). */
static size_t write_string(char *out, const char *s, size_t size)
{
    static const char hex[] = "0123456789abcdef";
    size_t n = 0;

    out[n++] = '"';
    for (size_t i = 0; i < size; i++) {
        unsigned char c = (unsigned char)s[i];
        char esc = 0;
        switch (c) {
        case '"': esc = '"'; break;
        case '\\': esc = '\\'; break;
        case '\b': esc = 'b'; break;
        case '\f': esc = 'f'; break;
        case '\n': esc = 'n'; break;
        case '\r': esc = 'r'; break;
        case '\t': esc = 't'; break;
        default: break;
        }
        if (esc) {
            out[n++] = '\\';
            out[n++] = esc;
        } else if (c < 32) {
            memcpy(out + n, "\\u00", 4);
            out[n + 4] = hex[c >> 4];
            out[n + 5] = hex[c & 15];
            n += 6;
        } else {
            out[n++] = (char)c;
        }
    }
    out[n++] = '"';
    return n;
}

/* ---- members ---- */

void cmd_json_begin(struct cmd_json *j, const char *name)
{
    size_t n = strlen(name);

    j->member_count = 0;
    j->text_used = 0;
    j->overflow = n >= sizeof(j->name);
    j->non_finite = false;
    if (j->overflow)
        n = sizeof(j->name) - 1;
    memcpy(j->name, name, n);
    j->name[n] = '\0';
}

/* Keeps 'size' bytes in the text pool; its offset, or -1 when full. */
static int keep(struct cmd_json *j, const char *data, size_t size)
{
    if (size > sizeof(j->text) - j->text_used) {
        j->overflow = true;
        return -1;
    }
    memcpy(j->text + j->text_used, data, size);
    j->text_used += size;
    return (int)(j->text_used - size);
}

static struct cmd_json_member *find_member(struct cmd_json *j, const char *key, size_t size)
{
    for (unsigned m = 0; m < j->member_count; m++)
        if (j->members[m].key_size == size && memcmp(j->text + j->members[m].key, key, size) == 0)
            return &j->members[m];
    return NULL;
}

static struct cmd_json_member *append_member(struct cmd_json *j, const char *key, size_t size,
                                             bool array)
{
    int at = keep(j, key, size);
    if (at < 0 || j->member_count == CMD_JSON_MEMBERS) {
        j->overflow = true;
        return NULL;
    }
    struct cmd_json_member *m = &j->members[j->member_count++];
    memset(m, 0, sizeof(*m));
    m->key = (uint16_t)at;
    m->key_size = (uint16_t)size;
    m->array = array;
    return m;
}

/*
 * Sets 'key' to the value text 'value' of 'size' bytes, as the gateway's
 * cJSON code did: a plain key replaces the first member of that name and
 * goes to the end; "name[i]" sets element i of the first member of that
 * name if it is an array, else of a new array member, filled with nulls.
 */
static void set_value(struct cmd_json *j, const char *key, const char *value, size_t size)
{
    const char *bracket = strchr(key, '[');
    int at = keep(j, value, size);

    if (at < 0)
        return;
    if (!bracket) {
        size_t key_size = strlen(key);
        struct cmd_json_member *old = find_member(j, key, key_size);
        if (old) {
            unsigned i = (unsigned)(old - j->members);
            memmove(old, old + 1, (j->member_count - i - 1) * sizeof(*old));
            j->member_count--;
        }
        struct cmd_json_member *m = append_member(j, key, key_size, false);
        if (m) {
            m->at[0] = (uint16_t)at;
            m->size[0] = (uint16_t)size;
        }
        return;
    }
    size_t name_size = (size_t)(bracket - key);
    int index = atoi(bracket + 1);
    struct cmd_json_member *m = find_member(j, key, name_size);
    if (!m || !m->array)
        m = append_member(j, key, name_size, true);
    if (!m)
        return;
    if (index < 0 || index >= CMD_JSON_ITEMS) {
        j->overflow = true;
        return;
    }
    while (m->count <= index)
        m->size[m->count++] = 0; /* null */
    m->at[index] = (uint16_t)at;
    m->size[index] = (uint16_t)size;
}

void cmd_json_set_number(struct cmd_json *j, const char *key, double value, bool from_float)
{
    char text[40];
    if (!isfinite(value))
        j->non_finite = true;
    set_value(j, key, text, cmd_json_number(text, value, from_float));
}

void cmd_json_set_string(struct cmd_json *j, const char *key, const char *value)
{
    size_t size = strlen(value);
    char local[512];
    char *text = size * 6 + 2 <= sizeof(local) ? local : malloc(size * 6 + 2);

    if (!text) {
        j->overflow = true;
        return;
    }
    set_value(j, key, text, write_string(text, value, size));
    if (text != local)
        free(text);
}

static const char *skip_blanks(const char *p)
{
    while (*p == ' ' || *p == '\t')
        p++;
    return p;
}

int cmd_json_set_fixed(struct cmd_json *j, const char *fixed)
{
    struct {
        const char *key;
        size_t key_size;
        long long value;
    } found[CMD_JSON_MEMBERS];
    unsigned n = 0;
    const char *p = skip_blanks(fixed);

    while (*p) {
        if (*p != '"' || n == CMD_JSON_MEMBERS)
            return -EINVAL;
        const char *key = ++p;
        while (*p && *p != '"' && *p != '\\')
            p++;
        if (*p != '"')
            return -EINVAL;
        found[n].key = key;
        found[n].key_size = (size_t)(p - key);
        p = skip_blanks(p + 1);
        if (*p++ != ':')
            return -EINVAL;
        p = skip_blanks(p);
        char *end;
        errno = 0;
        found[n].value = strtoll(p, &end, 10);
        if (end == p || errno || found[n].value < INT_MIN || found[n].value > INT_MAX ||
            *end == '.' || *end == 'e' || *end == 'E')
            return -EINVAL;
        n++;
        p = skip_blanks(end);
        if (*p == ',')
            p = skip_blanks(p + 1);
        else if (*p)
            return -EINVAL;
    }
    /* Appended as they stand, as cJSON took them from the parsed text. */
    for (unsigned i = 0; i < n; i++) {
        char text[24];
        size_t size = write_integer(text, found[i].value);
        int at = keep(j, text, size);
        struct cmd_json_member *m = at < 0 ? NULL
                                           : append_member(j, found[i].key, found[i].key_size,
                                                           false);
        if (!m)
            return 0; /* overflow: finish fails */
        m->at[0] = (uint16_t)at;
        m->size[0] = (uint16_t)size;
    }
    return 0;
}

char *cmd_json_finish(const struct cmd_json *j)
{
    if (j->overflow)
        return NULL;
    /* Keys and the name escaped (6 bytes a byte at most), values as kept. */
    size_t room = 16 + strlen(j->name) * 6 + j->text_used * 6 +
                  j->member_count * (8 + CMD_JSON_ITEMS * 5);
    char *out = malloc(room);
    size_t n = 0;

    if (!out)
        return NULL;
    memcpy(out, "{\"cmdName\":", 11);
    n = 11;
    n += write_string(out + n, j->name, strlen(j->name));
    for (unsigned i = 0; i < j->member_count; i++) {
        const struct cmd_json_member *m = &j->members[i];
        out[n++] = ',';
        n += write_string(out + n, j->text + m->key, m->key_size);
        out[n++] = ':';
        if (m->array)
            out[n++] = '[';
        unsigned count = m->array ? m->count : 1;
        for (unsigned k = 0; k < count; k++) {
            if (k)
                out[n++] = ',';
            if (m->size[k] == 0) {
                memcpy(out + n, "null", 4);
                n += 4;
            } else {
                memcpy(out + n, j->text + m->at[k], m->size[k]);
                n += m->size[k];
            }
        }
        if (m->array)
            out[n++] = ']';
    }
    out[n++] = '}';
    out[n] = '\0';
    return out;
}
