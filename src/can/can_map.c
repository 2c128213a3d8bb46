/* SPDX-License-Identifier: MIT */
/* can_map.c - check, encode and document the CAN frame map (can_map.h). */
#include "can_map.h"

#include "log.h"

#include <errno.h>
#include <math.h>
#include <string.h>

#define NOT_SENT_NAME "NotSent"

const char *const can_group_names[CAN_GROUP_COUNT] = {
#define CAN_GROUP_NAME(name) [CAN_GROUP_##name] = #name,
    CAN_GROUPS(CAN_GROUP_NAME)
#undef CAN_GROUP_NAME
};

static double effective(double x)
{
    return x == 0 ? 1 : x;
}

static int check_signal(const struct can_frame_def *f, const struct can_signal *s,
                        uint64_t *used)
{
    const char *why = NULL;

    if (s->bits == 0 || s->bits > 32 || s->start_bit + s->bits > f->dlc * 8)
        why = "does not fit its frame";
    else if (s->encoding == CAN_ENC_FLAG && (s->bits != 2 || s->source != CAN_SRC_STATUS))
        why = "is a flag: 2 bits of a status field";
    else if (s->encoding == CAN_ENC_BIT && s->bits != 1)
        why = "is a bit: 1 bit";
    else if (s->encoding == CAN_ENC_SIGNED && s->bits < 2)
        why = "is signed: at least 2 bits";
    else if (s->source == CAN_SRC_STATUS &&
             (s->id < 0 || s->id >= STATUS_FIELD_COUNT ||
              status_fields[s->id].kind != STATUS_KIND_NUM ||
              s->index >= status_fields[s->id].capacity))
        why = "names no number of the status model";
    else if (s->source == CAN_SRC_GW && (s->id < 0 || s->id >= GW_VALUE_COUNT))
        why = "names no gateway value";
    else if (s->source == CAN_SRC_MIRROR && (s->id < 0 || s->id >= CAN_MIRROR_VALUE_COUNT))
        why = "names no mirror value";
    if (!why) {
        uint64_t mask = ((s->bits == 64 ? 0 : (uint64_t)1 << s->bits) - 1) << s->start_bit;
        if (*used & mask)
            why = "shares bits with another signal";
        *used |= mask;
    }
    if (why) {
        log_err("CAN map: signal %s of frame %s %s", s->name, f->name, why);
        return -EINVAL;
    }
    return 0;
}

int can_map_check(void)
{
    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        uint64_t used = 0;

        if (f->dlc == 0 || f->dlc > CAN_FRAME_MAX_DLC || f->group >= CAN_GROUP_COUNT ||
            f->signal_count == 0) {
            log_err("CAN map: frame %s: bad length, group or signal list", f->name);
            return -EINVAL;
        }
        for (unsigned j = 0; j < i; j++) {
            if (can_map_frames[j].id_offset == f->id_offset ||
                strcmp(can_map_frames[j].name, f->name) == 0) {
                log_err("CAN map: frame %s repeats the offset or name of frame %s",
                        f->name, can_map_frames[j].name);
                return -EINVAL;
            }
        }
        for (unsigned k = 0; k < f->signal_count; k++) {
            if (check_signal(f, &f->signals[k], &used))
                return -EINVAL;
            /* Names are unique in the whole map: a receiver may flatten it. */
            for (unsigned j = 0; j <= i; j++) {
                const struct can_frame_def *g = &can_map_frames[j];
                unsigned end = j == i ? k : g->signal_count;
                for (unsigned m = 0; m < end; m++) {
                    if (strcmp(g->signals[m].name, f->signals[k].name) == 0) {
                        log_err("CAN map: signal name %s is used twice",
                                f->signals[k].name);
                        return -EINVAL;
                    }
                }
            }
        }
    }
    return 0;
}

void can_signal_range(const struct can_signal *sig, struct can_signal_range *out)
{
    bool robot = sig->source == CAN_SRC_STATUS;

    memset(out, 0, sizeof(*out));
    switch (sig->encoding) {
    case CAN_ENC_FLAG:
        out->max = 1;
        out->has_invalid = true;
        out->invalid = 3;
        return;
    case CAN_ENC_BIT:
        out->max = 1;
        return;
    case CAN_ENC_UNSIGNED:
        out->max = (int64_t)(((uint64_t)1 << sig->bits) - 1);
        if (robot) {
            out->has_invalid = true;
            out->invalid = out->max;
            out->max--;
        }
        return;
    case CAN_ENC_SIGNED:
        out->min = -((int64_t)1 << (sig->bits - 1));
        out->max = ((int64_t)1 << (sig->bits - 1)) - 1;
        if (robot) {
            out->has_invalid = true;
            out->invalid = out->min;
            out->min++;
        }
        return;
    }
}

int64_t can_signal_raw(const struct can_signal *sig, const struct can_inputs *in)
{
    struct can_signal_range r;
    bool present = true;
    double v = 0;

    can_signal_range(sig, &r);
    switch (sig->source) {
    case CAN_SRC_STATUS:
        if (in->status) {
            const struct status_num *n = status_num_at(in->status, sig->id, sig->index);
            present = n->present;
            v = n->value;
        } else {
            present = false;
        }
        break;
    case CAN_SRC_GW:
        v = in->gw ? in->gw[sig->id] : 0;
        break;
    case CAN_SRC_MIRROR:
        v = in->mirror[sig->id];
        break;
    }
    if (!present || isnan(v))
        return r.has_invalid ? r.invalid : 0;
    if (sig->encoding == CAN_ENC_FLAG || sig->encoding == CAN_ENC_BIT)
        return v != 0;
    double scaled = round(v * effective(sig->source_scale) / effective(sig->factor));
    if (scaled <= (double)r.min)
        return r.min;
    if (scaled >= (double)r.max)
        return r.max;
    return (int64_t)scaled;
}

void can_map_encode(const struct can_frame_def *frame, const struct can_inputs *in,
                    uint8_t data[CAN_FRAME_MAX_DLC])
{
    uint64_t word = 0;

    for (unsigned k = 0; k < frame->signal_count; k++) {
        const struct can_signal *s = &frame->signals[k];
        uint64_t mask = ((uint64_t)1 << s->bits) - 1;
        word |= ((uint64_t)can_signal_raw(s, in) & mask) << s->start_bit;
    }
    /* Little-endian: bit 0 of the word is bit 0 of byte 0. */
    for (unsigned i = 0; i < CAN_FRAME_MAX_DLC; i++)
        data[i] = i < frame->dlc ? (uint8_t)(word >> (8 * i)) : 0;
}

uint32_t can_frame_id(const struct can_frame_def *frame, uint32_t base_id)
{
    return base_id + frame->id_offset;
}

unsigned can_map_max_offset(void)
{
    unsigned max = 0;
    for (unsigned i = 0; i < can_map_frame_count; i++)
        if (can_map_frames[i].id_offset > max)
            max = can_map_frames[i].id_offset;
    return max;
}

/* ---- DBC ---- */

static void put_dbc_string(FILE *out, const char *s)
{
    fputc('"', out);
    for (; *s; s++) {
        if (*s == '"' || *s == '\\')
            fputc('\\', out);
        fputc(*s, out);
    }
    fputc('"', out);
}

/* DBC identifiers: bit 31 marks an extended (29-bit) identifier. */
static unsigned long dbc_id(const struct can_frame_def *f, const struct can_dbc_options *opt)
{
    return can_frame_id(f, opt->base_id) | (opt->extended_ids ? 0x80000000ul : 0);
}

static bool listed(const struct can_frame_def *f, const struct can_dbc_options *opt)
{
    return opt->groups & (1u << f->group);
}

static void print_signal(const struct can_signal *s, FILE *out)
{
    struct can_signal_range r;
    double factor = effective(s->factor);

    can_signal_range(s, &r);
    fprintf(out, " SG_ %s : %u|%u@1%c (%.15g,0) [%.15g|%.15g] ", s->name, s->start_bit,
            s->bits, s->encoding == CAN_ENC_SIGNED ? '-' : '+', factor,
            (double)r.min * factor, (double)r.max * factor);
    put_dbc_string(out, s->unit);
    fprintf(out, " Vector__XXX\n");
}

static void print_signal_comment(unsigned long id, const struct can_signal *s, FILE *out)
{
    char text[512];
    struct can_signal_range r;

    can_signal_range(s, &r);
    if (r.has_invalid)
        snprintf(text, sizeof(text), "%s. Raw %lld: the robot did not send it.",
                 s->description, (long long)r.invalid);
    else
        snprintf(text, sizeof(text), "%s.", s->description);
    fprintf(out, "CM_ SG_ %lu %s ", id, s->name);
    put_dbc_string(out, text);
    fprintf(out, ";\n");
}

static void print_signal_values(unsigned long id, const struct can_signal *s, FILE *out)
{
    struct can_signal_range r;

    can_signal_range(s, &r);
    if (!s->values && !r.has_invalid)
        return;
    fprintf(out, "VAL_ %lu %s", id, s->name);
    if (r.has_invalid)
        fprintf(out, " %lld \"" NOT_SENT_NAME "\"", (long long)r.invalid);
    for (const struct can_value_name *v = s->values; v && v->name; v++)
        fprintf(out, " %lld \"%s\"", (long long)v->raw, v->name);
    fprintf(out, " ;\n");
}

int can_map_print_dbc(const struct can_dbc_options *opt, FILE *out)
{
    static const char *const new_symbols[] = {
        "NS_DESC_", "CM_", "BA_DEF_", "BA_", "VAL_", "BA_DEF_DEF_",
        "SIG_VALTYPE_", "BO_TX_BU_",
    };

    fprintf(out, "VERSION \"jakagw %s CAN map %d\"\n\n\nNS_ :\n", JAKAGW_VERSION,
            CAN_MAP_VERSION);
    for (unsigned i = 0; i < sizeof(new_symbols) / sizeof(new_symbols[0]); i++)
        fprintf(out, "\t%s\n", new_symbols[i]);
    fprintf(out, "\nBS_:\n\nBU_: " CAN_MAP_NODE "\n\n");
    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        if (!listed(f, opt))
            continue;
        fprintf(out, "\nBO_ %lu %s: %u " CAN_MAP_NODE "\n", dbc_id(f, opt), f->name, f->dlc);
        for (unsigned k = 0; k < f->signal_count; k++)
            print_signal(&f->signals[k], out);
    }
    fprintf(out, "\n\nCM_ ");
    put_dbc_string(out,
                   "jakagw CAN mirror (generated by jakagw --print-dbc): key status of a "
                   "JAKA robot, from the same status model as the Modbus map. Classic "
                   "CAN, signals little-endian, every frame sent each period. A value "
                   "the robot did not send carries the reserved raw value named " NOT_SENT_NAME
                   " (flags 3, unsigned all bits set, signed the most negative "
                   "value); a real value saturates one step short of it. Check "
                   "JAKA_Health StatusFresh before trusting the robot frames, and "
                   "RollingCounter to detect a frozen gateway.");
    fprintf(out, ";\nCM_ BU_ " CAN_MAP_NODE " \"The jakagw gateway\";\n");
    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        if (!listed(f, opt))
            continue;
        fprintf(out, "CM_ BO_ %lu ", dbc_id(f, opt));
        put_dbc_string(out, f->description);
        fprintf(out, ";\n");
        for (unsigned k = 0; k < f->signal_count; k++)
            print_signal_comment(dbc_id(f, opt), &f->signals[k], out);
    }
    fprintf(out, "BA_DEF_ BO_ \"GenMsgCycleTime\" INT 0 65535;\n"
                 "BA_DEF_DEF_ \"GenMsgCycleTime\" 0;\n");
    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        if (listed(f, opt))
            fprintf(out, "BA_ \"GenMsgCycleTime\" BO_ %lu %u;\n", dbc_id(f, opt),
                    opt->period_ms);
    }
    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        if (!listed(f, opt))
            continue;
        for (unsigned k = 0; k < f->signal_count; k++)
            print_signal_values(dbc_id(f, opt), &f->signals[k], out);
    }
    fprintf(out, "\n");
    return ferror(out) ? -EIO : 0;
}

/* ---- group lists ---- */

static void format_list(uint32_t groups, char *buf, size_t size)
{
    size_t used = 0;

    buf[0] = '\0';
    for (int g = 0; g < CAN_GROUP_COUNT && used < size; g++) {
        if (groups & (1u << g)) {
            int n = snprintf(buf + used, size - used, "%s%s", used ? "," : "",
                             can_group_names[g]);
            if (n < 0)
                return;
            used += (size_t)n;
        }
    }
}

int can_map_parse_groups(const char *text, uint32_t *groups, char *why, size_t why_size)
{
    uint32_t mask = 0;
    const char *p = text;

    while (*p) {
        size_t len;
        p += strspn(p, ", \t");
        len = strcspn(p, ", \t");
        if (len == 0)
            break;
        if (len == 3 && strncmp(p, "all", 3) == 0) {
            mask = CAN_GROUPS_ALL;
        } else {
            int g;
            for (g = 0; g < CAN_GROUP_COUNT; g++)
                if (strlen(can_group_names[g]) == len && strncmp(p, can_group_names[g], len) == 0)
                    break;
            if (g == CAN_GROUP_COUNT) {
                char names[128];
                format_list(CAN_GROUPS_ALL, names, sizeof(names));
                snprintf(why, why_size, "'%.*s' is not a frame group: all or a list of %s",
                         (int)len, p, names);
                return -EINVAL;
            }
            mask |= 1u << g;
        }
        p += len;
    }
    if (mask == 0) {
        snprintf(why, why_size, "lists no frame group");
        return -EINVAL;
    }
    *groups = mask;
    return 0;
}

void can_map_format_groups(uint32_t groups, char *buf, size_t size)
{
    if (size == 0)
        return;
    if ((groups & CAN_GROUPS_ALL) == CAN_GROUPS_ALL)
        snprintf(buf, size, "all");
    else
        format_list(groups, buf, size);
}
