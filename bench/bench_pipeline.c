/* SPDX-License-Identifier: MIT */
/*
 * bench_pipeline.c - what one status document costs the gateway, as ratios
 * to a reference measured in the same run: cJSON's own parse and free of
 * the same document (the least any JSON consumer pays). Also what one
 * Modbus read costs, as a ratio to moving the same reply bytes through the
 * same socketpair without libmodbus.
 *
 * Each figure is the median of 15 rounds; the machine may be shared and
 * noisy, so compare ratios, not nanoseconds across runs.
 */
#include <cJSON.h>
#include <errno.h>
#include <modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "framer.h"
#include "log.h"
#include "mb_request.h"
#include "regmap.h"
#include "status.h"

#define ROUNDS 15

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

typedef void (*work_fn)(void *ctx);

struct result {
    double ns;    /* median ns per call */
    double ratio; /* median of the per-round ratios to the reference */
};

static double time_calls(work_fn fn, void *ctx, int iters)
{
    double start = now_ns();
    for (int i = 0; i < iters; i++)
        fn(ctx);
    return (now_ns() - start) / iters;
}

/*
 * Each round times the reference and the work back to back, so a burst of
 * load on a shared machine hits both; the ratio is the median of the
 * per-round ratios.
 */
static struct result measure(work_fn ref, work_fn fn, void *ctx, int iters)
{
    double t[ROUNDS], ratio[ROUNDS];
    for (int r = 0; r < ROUNDS; r++) {
        double tr = time_calls(ref, ctx, iters);
        t[r] = time_calls(fn, ctx, iters);
        ratio[r] = t[r] / tr;
    }
    qsort(t, ROUNDS, sizeof(t[0]), cmp_double);
    qsort(ratio, ROUNDS, sizeof(ratio[0]), cmp_double);
    return (struct result){t[ROUNDS / 2], ratio[ROUNDS / 2]};
}

struct doc_ctx {
    const char *doc;
    size_t size;
    struct jaka_status st;
    struct framer framer;
    struct regmap_image img;
    unsigned objects;
};

static void ref_cjson(void *p)
{
    struct doc_ctx *c = p;
    cJSON_Delete(cJSON_ParseWithLength(c->doc, c->size));
}

static void on_object(void *user, enum framer_event ev, const char *d, size_t n)
{
    (void)d;
    (void)n;
    if (ev == FRAMER_EVENT_OBJECT)
        ((struct doc_ctx *)user)->objects++;
}

static void run_framer(void *p)
{
    struct doc_ctx *c = p;
    framer_feed(&c->framer, c->doc, c->size);
}

static void run_parse(void *p)
{
    struct doc_ctx *c = p;
    status_parse(&c->st, c->doc, c->size);
}

static void run_encode(void *p)
{
    struct doc_ctx *c = p;
    regmap_encode_status(&c->img, &c->st);
}

static void run_all(void *p)
{
    run_framer(p);
    run_parse(p);
    run_encode(p);
}

struct mb_ctx {
    modbus_t *ctx;
    int pair[2];
    struct regmap_image *img;
    uint8_t req[12];
    uint8_t rsp[300];
    size_t rsp_size;
};

static void ref_socketpair(void *p)
{
    struct mb_ctx *c = p;
    if (send(c->pair[0], c->rsp, c->rsp_size, 0) < 0 ||
        recv(c->pair[1], c->rsp, sizeof(c->rsp), 0) < 0)
        abort();
}

static void run_reply(void *p)
{
    struct mb_ctx *c = p;
    if (mb_request_check(c->img, c->req + 7, 5) != 0 ||
        modbus_reply(c->ctx, c->req, 12, c->img->mb) < 0 ||
        recv(c->pair[1], c->rsp, sizeof(c->rsp), 0) < 0)
        abort();
}

int main(int argc, char **argv)
{
    const char *path = argc > 1 ? argv[1] : "tests/data/status-controller-a.json";
    FILE *f = fopen(path, "rb");
    static struct doc_ctx c;
    struct regmap map;

    if (!f) {
        fprintf(stderr, "bench: cannot open %s: %s\n", path, strerror(errno));
        return 1;
    }
    static char buf[1 << 20];
    c.size = fread(buf, 1, sizeof(buf), f);
    fclose(f);
    while (c.size && (buf[c.size - 1] == '\n' || buf[c.size - 1] == '\r'))
        c.size--;
    c.doc = buf;
    if (regmap_init(&map) || regmap_image_init(&c.img, &map, REGMAP_HIGH_WORD_FIRST) ||
        framer_init(&c.framer, FRAMER_DEFAULT_MAX_OBJECT, on_object, &c))
        return 1;
    if (status_parse(&c.st, c.doc, c.size) != 0) {
        fprintf(stderr, "bench: %s is not a status document\n", path);
        return 1;
    }

    int iters = 200;
    struct result ref = measure(ref_cjson, ref_cjson, &c, iters);
    struct result fr = measure(ref_cjson, run_framer, &c, iters);
    struct result pa = measure(ref_cjson, run_parse, &c, iters);
    struct result en = measure(ref_cjson, run_encode, &c, iters);
    struct result all = measure(ref_cjson, run_all, &c, iters);
    printf("status document: %zu bytes (%s), medians of %d rounds of %d\n", c.size, path,
           ROUNDS, iters);
    printf("  reference  cJSON parse + free       %8.1f us  1.00\n", ref.ns / 1000);
    printf("  framer     find the document        %8.1f us  %.2f\n", fr.ns / 1000, fr.ratio);
    printf("  parse      into struct jaka_status  %8.1f us  %.2f\n", pa.ns / 1000, pa.ratio);
    printf("  encode     the whole register image %8.1f us  %.2f\n", en.ns / 1000, en.ratio);
    printf("  total      per document             %8.1f us  %.2f  (%.1f%% of a 30 ms period)\n",
           all.ns / 1000, all.ratio, all.ns / 300000.0);
    if (c.objects == 0)
        return 1;

    static struct mb_ctx m;
    if (socketpair(AF_UNIX, SOCK_SEQPACKET, 0, m.pair) < 0)
        return 1;
    m.ctx = modbus_new_tcp(NULL, 0);
    modbus_set_socket(m.ctx, m.pair[0]);
    m.img = &c.img;
    const uint8_t req[12] = {0, 1, 0, 0, 0, 6, 1, 4, 0x00, 0xC8, 0x00, 125};
    memcpy(m.req, req, sizeof(req));
    m.rsp_size = 9 + 250; /* the same reply size: 125 registers */
    iters = 2000;
    struct result sref = measure(ref_socketpair, ref_socketpair, &m, iters);
    struct result rep = measure(ref_socketpair, run_reply, &m, iters);
    printf("Modbus read of 125 input registers, medians of %d rounds of %d\n", ROUNDS, iters);
    printf("  reference  same bytes through the socketpair %6.2f us  1.00\n", sref.ns / 1000);
    printf("  check + modbus_reply + drain                 %6.2f us  %.2f\n", rep.ns / 1000,
           rep.ratio);
    modbus_set_socket(m.ctx, -1);
    modbus_free(m.ctx);
    close(m.pair[0]);
    close(m.pair[1]);
    framer_free(&c.framer);
    regmap_image_free(&c.img);
    regmap_free(&map);
    return 0;
}
