/* SPDX-License-Identifier: MIT */
/*
 * vendor_client.c - see vendor_client.h.
 *
 * What each vendor's client does comes from the table below, each row
 * citing the vendor's documentation; what it reads and writes comes from
 * the shipped example (the request file). Two paces:
 * - a client thread that works its queue one request after another, as
 *   fast as the server answers, publishing what it read at the next task
 *   cycle (CODESYS's Modbus TCP master, a ProSoft module's command list);
 * - a client block per instance that holds one request, started in one
 *   task cycle and seen DONE in a later one: one request per instance per
 *   task cycle at best (Siemens MB_CLIENT, TwinCAT's Tc2_ModbusSrv).
 * A refused write (a Modbus exception) is an answer: not repeated until
 * the image changes again. A connection error closes the instance's
 * connection; the next cycle connects again, and what was written is then
 * taken to be 0, as a gateway holds it after a restart: every register and
 * coil that is not 0 in the image is written again (the examples clear
 * their record of what was sent when a connection is made).
 */
#define _GNU_SOURCE
#include "vendor_client.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <modbus.h>

enum pace { PACE_QUEUE, PACE_ONE_PER_CYCLE };

static const struct vendor_rules {
    const char *name;
    enum pace pace;
    const char *source;
} vendor_rules[] = {
    {"codesys", PACE_QUEUE,
     "CODESYS Online Help, Modbus TCP Slave, Modbus Slave Channel: one channel per function "
     "code and range, triggered cyclically (its cycle time), on a rising edge or by the "
     "application; the master sends a slave's requests one at a time, in the channel list's "
     "order; inputs reach the application at the next bus cycle"},
    {"siemens", PACE_ONE_PER_CYCLE,
     "SIMATIC S7-1200/S7-1500 MB_CLIENT (V5): one job per instance at a time, started with "
     "REQ, DONE or ERROR in a later call; each instance its own connection (TCON_IP_v4 ID)"},
    {"twincat", PACE_ONE_PER_CYCLE,
     "Beckhoff TF6250 Tc2_ModbusSrv FB_MBReadInputRegs, FB_MBReadInputs, FB_MBWriteRegs, "
     "FB_MBWriteSingleCoil: one request per block, started by a rising edge of bExecute, "
     "bBusy for one or more cycles"},
    {"rockwell", PACE_QUEUE,
     "ProSoft MVI56E-MNETC user manual, Modbus client command list: commands in list order, "
     "one at a time; Enable 1 continuous (every Poll Interval), 2 conditional (a write only "
     "when its data changed); Minimum Command Delay between two commands"},
};

enum table { T_IR, T_DI, T_HR, T_CO };
enum trigger { TRIG_CYCLIC, TRIG_CHANGE, TRIG_TURN };

#define MAX_REQUESTS 64
#define MAX_INSTANCES 4

struct request {
    int instance;
    enum table table;
    int first, count;
    enum trigger trigger;
    int period_ms;
    bool heartbeat, single;
    long long last_us;     /* when last sent */
    uint16_t data[256];    /* read: what arrived; write: what was written */
    bool arrived;          /* read: data waits for the next task cycle */
};

struct instance {
    modbus_t *ctx;
    long long retry_us;
    int next_read;         /* PACE_ONE_PER_CYCLE: the read whose turn it is */
    bool last_was_heartbeat;
};

static struct {
    const struct vendor_rules *rules;
    const char *host;
    int port;
    int delay_ms;          /* between two requests (ProSoft's Minimum Command Delay) */
    bool first_changed;    /* "writes first": the writer takes the first block that changed */
    bool keep_on_reconnect; /* "reconnect keeps": what was written is not written again */
    struct request req[MAX_REQUESTS];
    int n_req;
    struct instance inst[MAX_INSTANCES];
    struct vc_image img;
    long long last_run_us;
    struct vc_stats stats;
} vc;

static long long monotonic_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1000000LL + ts.tv_nsec / 1000;
}

static int parse_table(const char *s, enum table *t)
{
    static const char *names[] = {"ir", "di", "hr", "co"};
    for (int i = 0; i < 4; i++)
        if (strcmp(s, names[i]) == 0) {
            *t = (enum table)i;
            return 0;
        }
    return -1;
}

static int parse_request(char *line)
{
    struct request *r = &vc.req[vc.n_req];
    char table[8], trig[16];
    int used = 0;

    memset(r, 0, sizeof(*r));
    if (sscanf(line, "request %d %7s %d %d %15s %n", &r->instance, table, &r->first, &r->count,
               trig, &used) != 5 || parse_table(table, &r->table) != 0 || r->instance < 0 ||
        r->instance >= MAX_INSTANCES || r->count < 1 ||
        r->count > (r->table == T_IR || r->table == T_HR ? 125 : 256))
        return -1;
    char *rest = line + used;
    if (strcmp(trig, "cyclic") == 0) {
        r->trigger = TRIG_CYCLIC;
        if (sscanf(rest, "%d%n", &r->period_ms, &used) != 1 || r->period_ms < 1)
            return -1;
        rest += used;
    } else if (strcmp(trig, "change") == 0) {
        r->trigger = TRIG_CHANGE;
    } else if (strcmp(trig, "turn") == 0) {
        r->trigger = TRIG_TURN;
    } else {
        return -1;
    }
    r->heartbeat = strstr(rest, "heartbeat") != NULL;
    r->single = strstr(rest, "single") != NULL;
    vc.n_req++;
    return 0;
}

int vc_load(const char *path, const char *host, int port)
{
    char line[256], name[32];
    FILE *f = fopen(path, "r");

    if (!f) {
        fprintf(stderr, "vendor_client: %s: %s\n", path, strerror(errno));
        return -1;
    }
    memset(&vc, 0, sizeof(vc));
    vc.host = host;
    vc.port = port;
    for (int n = 1; fgets(line, sizeof(line), f); n++) {
        line[strcspn(line, "#\n")] = '\0';
        int ok = 0;
        if (line[strspn(line, " ")] == '\0')
            continue;
        if (sscanf(line, "vendor %31s", name) == 1) {
            for (size_t i = 0; i < sizeof(vendor_rules) / sizeof(vendor_rules[0]); i++)
                if (strcmp(vendor_rules[i].name, name) == 0)
                    vc.rules = &vendor_rules[i];
            ok = vc.rules != NULL;
        } else if (sscanf(line, "delay %d", &vc.delay_ms) == 1) {
            ok = vc.delay_ms >= 0;
        } else if (strncmp(line, "reconnect keeps", 15) == 0) {
            vc.keep_on_reconnect = true;
            ok = 1;
        } else if (strncmp(line, "writes first", 12) == 0) {
            vc.first_changed = true;
            ok = 1;
        } else if (vc.n_req < MAX_REQUESTS) {
            ok = parse_request(line) == 0;
        }
        if (!ok) {
            fprintf(stderr, "vendor_client: %s:%d: cannot read '%s'\n", path, n, line);
            fclose(f);
            return -1;
        }
    }
    fclose(f);
    if (!vc.rules || vc.n_req == 0) {
        fprintf(stderr, "vendor_client: %s: no vendor or no request\n", path);
        return -1;
    }
    return 0;
}

void vc_bind(const struct vc_image *image)
{
    vc.img = *image;
    for (int i = 0; i < vc.n_req; i++) {
        memset(vc.req[i].data, 0, sizeof(vc.req[i].data));
        vc.req[i].arrived = false;
    }
}

const struct vc_stats *vc_stats(void) { return &vc.stats; }
const char *vc_vendor(void) { return vc.rules ? vc.rules->name : "?"; }

static bool is_read(const struct request *r) { return r->table == T_IR || r->table == T_DI; }

static modbus_t *connection(int i, long long now)
{
    struct instance *in = &vc.inst[i];
    if (in->ctx || now < in->retry_us)
        return in->ctx;
    modbus_t *ctx = modbus_new_tcp(vc.host, vc.port);
    if (!ctx)
        return NULL;
    modbus_set_response_timeout(ctx, 0, 500000);
    if (modbus_connect(ctx) != 0) {
        modbus_free(ctx);
        in->retry_us = now + 200000;
        return NULL;
    }
    in->ctx = ctx;
    /* A new connection: the gateway may have restarted and hold 0
     * everywhere; what is not 0 in the image is written again. */
    for (int k = 0; k < vc.n_req && !vc.keep_on_reconnect; k++)
        if (vc.req[k].instance == i && !is_read(&vc.req[k]))
            memset(vc.req[k].data, 0, sizeof(vc.req[k].data));
    return ctx;
}

static void drop(int i, const char *what)
{
    struct instance *in = &vc.inst[i];
    vc.stats.failures++;
    fprintf(stderr, "vendor_client: %s: %s: instance %d reconnects\n", what, modbus_strerror(errno), i);
    modbus_close(in->ctx);
    modbus_free(in->ctx);
    in->ctx = NULL;
    in->retry_us = monotonic_us() + 200000;
}

/* The image's values of a write range, as registers (coils 0/1). */
static void image_of(const struct request *r, uint16_t *out)
{
    for (int k = 0; k < r->count; k++)
        out[k] = r->table == T_HR ? vc.img.hr[r->first + k] : vc.img.co[r->first + k] ? 1 : 0;
}

static bool changed(const struct request *r)
{
    uint16_t now[256];
    image_of(r, now);
    return memcmp(now, r->data, r->count * sizeof(uint16_t)) != 0;
}

/* The first coil of a "single" range whose image differs from what was
 * written, or -1. */
static int changed_coil(const struct request *r)
{
    for (int k = 0; k < r->count; k++)
        if ((vc.img.co[r->first + k] ? 1 : 0) != r->data[k])
            return k;
    return -1;
}

static bool answered(int i, int rc, const struct request *r)
{
    if (rc >= 0)
        return true;
    if (errno >= MODBUS_ENOBASE && errno < MODBUS_ENOBASE + 20) {
        vc.stats.refused++;
        fprintf(stderr, "vendor_client: %s %d refused: %s\n",
                r->table == T_HR ? "write registers" : "write coils", r->first, modbus_strerror(errno));
        return true;
    }
    drop(i, "request");
    return false;
}

/* Sends request 'r' (for a "single" coil range: its coil 'coil'). */
static void send_request(struct request *r, int coil, long long now)
{
    modbus_t *ctx = connection(r->instance, now);
    uint8_t bits[256];
    uint16_t values[256];
    int rc;

    if (!ctx)
        return;
    vc.stats.requests++;
    r->last_us = now;
    switch (r->table) {
    case T_IR:
        rc = modbus_read_input_registers(ctx, r->first, r->count, r->data);
        break;
    case T_DI:
        rc = modbus_read_input_bits(ctx, r->first, r->count, bits);
        for (int k = 0; rc == r->count && k < r->count; k++)
            r->data[k] = bits[k];
        break;
    case T_HR:
        image_of(r, values);
        rc = modbus_write_registers(ctx, r->first, r->count, values);
        if (answered(r->instance, rc, r)) {
            memcpy(r->data, values, r->count * sizeof(uint16_t));
            vc.stats.writes++;
            if (r->heartbeat)
                vc.stats.heartbeat_writes++;
            else
                vc.stats.other_writes++;
        }
        return;
    case T_CO:
    default:
        image_of(r, values);
        if (r->single && strcmp(vc.rules->name, "twincat") == 0) {
            rc = modbus_write_bit(ctx, r->first + coil, values[coil]); /* FB_MBWriteSingleCoil: FC05 */
        } else if (r->single) {
            uint8_t one = (uint8_t)values[coil]; /* MB_MODE 2: FC15 of one coil */
            rc = modbus_write_bits(ctx, r->first + coil, 1, &one);
        } else {
            for (int k = 0; k < r->count; k++)
                bits[k] = (uint8_t)values[k];
            rc = modbus_write_bits(ctx, r->first, r->count, bits);
        }
        if (answered(r->instance, rc, r)) {
            if (r->single)
                r->data[coil] = values[coil];
            else
                memcpy(r->data, values, r->count * sizeof(uint16_t));
            vc.stats.writes++;
            vc.stats.coil_writes++;
        }
        return;
    }
    if (rc != r->count) {
        drop(r->instance, "read");
        return;
    }
    r->arrived = true;
    vc.stats.reads++;
}

void vc_publish_inputs(void)
{
    for (int i = 0; i < vc.n_req; i++) {
        struct request *r = &vc.req[i];
        if (!is_read(r) || !r->arrived)
            continue;
        for (int k = 0; k < r->count; k++) {
            if (r->table == T_IR)
                vc.img.ir[r->first + k] = r->data[k];
            else
                vc.img.di[r->first + k] = (uint8_t)r->data[k];
        }
        r->arrived = false;
    }
}

static bool due(const struct request *r, long long now)
{
    switch (r->trigger) {
    case TRIG_CYCLIC:
        return now - r->last_us >= (long long)r->period_ms * 1000;
    case TRIG_CHANGE:
        return r->single ? changed_coil(r) >= 0 : changed(r);
    case TRIG_TURN:
    default:
        return true;
    }
}

/* A client thread's queue: every request due, in list order, one at a
 * time; with a minimum delay between two, as many as the time since the
 * last run allows (at least one), the next run going on where this one
 * stopped (a command list is walked round, not restarted). */
static void run_queue(long long now)
{
    static int cursor;
    long budget = vc.n_req * 125; /* no limit but the delay */
    if (vc.delay_ms > 0) {
        long long since = vc.last_run_us ? now - vc.last_run_us : 0;
        budget = since / (vc.delay_ms * 1000LL);
        if (budget < 1)
            budget = 1;
    } else {
        cursor = 0; /* the whole list each cycle: always from its top */
    }
    for (int n = 0; n < vc.n_req && budget > 0; n++, cursor = (cursor + 1) % vc.n_req) {
        struct request *r = &vc.req[cursor];
        if (!due(r, now))
            continue;
        int coil = r->single ? changed_coil(r) : 0;
        /* A "single" coil range sends every changed coil, one per request. */
        do {
            send_request(r, coil < 0 ? 0 : coil, now);
            budget--;
            coil = r->single ? changed_coil(r) : -1;
        } while (r->single && coil >= 0 && budget > 0 && vc.inst[r->instance].ctx);
    }
}

/* The example's write rule for a one-request instance: the heartbeat when
 * it changed and the last write was not it; else the first parameter
 * block that changed (parameters before their triggers); else the first
 * changed coil; else the heartbeat. */
static void run_writer(int i, long long now)
{
    struct request *hb = NULL, *block = NULL, *coils = NULL;
    int coil = -1;
    for (int k = 0; k < vc.n_req; k++) {
        struct request *r = &vc.req[k];
        if (r->instance != i || is_read(r))
            continue;
        if (r->heartbeat && !hb && changed(r))
            hb = r;
        else if (r->table == T_HR && !r->heartbeat && !block && changed(r))
            block = r;
        else if (r->table == T_CO && !coils && (coil = changed_coil(r)) >= 0)
            coils = r;
    }
    struct instance *in = &vc.inst[i];
    struct request *pick = hb && !in->last_was_heartbeat ? hb : block ? block : coils ? coils : hb;
    if (vc.first_changed) /* the rule the examples had: blocks in list order, then coils */
        pick = hb ? hb : block ? block : coils;
    if (!pick)
        return;
    in->last_was_heartbeat = pick == hb;
    send_request(pick, pick == coils ? coil : 0, now);
}

/* One request per instance per task cycle: a reader takes its ranges in
 * turn, a writer picks by the example's rule. */
static void run_instances(long long now)
{
    for (int i = 0; i < MAX_INSTANCES; i++) {
        int reads = 0, first = -1;
        for (int k = 0; k < vc.n_req; k++)
            if (vc.req[k].instance == i && is_read(&vc.req[k])) {
                reads++;
                if (first < 0)
                    first = k;
            }
        if (reads == 0) {
            run_writer(i, now);
            continue;
        }
        struct instance *in = &vc.inst[i];
        int seen = 0;
        for (int k = in->next_read; seen < vc.n_req; k = (k + 1) % vc.n_req, seen++) {
            if (vc.req[k].instance != i || !is_read(&vc.req[k]))
                continue;
            send_request(&vc.req[k], 0, now);
            in->next_read = (k + 1) % vc.n_req;
            break;
        }
    }
}

void vc_run_requests(long long now_us)
{
    if (vc.rules->pace == PACE_QUEUE)
        run_queue(now_us);
    else
        run_instances(now_us);
    vc.last_run_us = now_us;
}

int vc_coil_written(int address)
{
    for (int i = 0; i < vc.n_req; i++) {
        const struct request *r = &vc.req[i];
        if (r->table == T_CO && address >= r->first && address < r->first + r->count)
            return r->data[address - r->first] ? 1 : 0;
    }
    return -1;
}

void vc_close(void)
{
    for (int i = 0; i < MAX_INSTANCES; i++)
        if (vc.inst[i].ctx) {
            modbus_close(vc.inst[i].ctx);
            modbus_free(vc.inst[i].ctx);
            vc.inst[i].ctx = NULL;
        }
}
