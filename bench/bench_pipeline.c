/* SPDX-License-Identifier: MIT */
/*
 * bench_pipeline.c - what one status document costs the gateway, as ratios
 * to a reference measured in the same run: cJSON's own parse and delete of
 * the same document with the default allocator (the least any consumer of
 * cJSON pays).
 *
 * The whole ingest path is measured as the gateway runs it for each
 * document: read() from a socket in reads of the robot link's buffer size,
 * framed, parsed into the spare struct jaka_status, swapped in, and the
 * register image re-encoded. (The CAN mirror reads the status on its own
 * timer, not per document, so a document costs it nothing.) Documents
 * vary as a moving robot's do: a set of variants of the given document
 * whose positions, velocities, joint monitor data and torque sensor values
 * differ from one to the next, so the encoder cannot skip everything.
 *
 * Two measures:
 *   - instructions, counted by callgrind (valgrind --tool=callgrind) in
 *     the function that runs the documents, over two run lengths so that
 *     anything done once cancels out. Counts hold on a noisy shared machine
 *     and carry over to ARM better than time does. Also the ten functions
 *     that cost the most in the ingest run (self instructions).
 *   - time, the median of 15 rounds, each round timing the reference and
 *     the work back to back.
 * Also what one Modbus read costs, as a ratio to moving the same reply
 * bytes through the same socketpair.
 *
 *   bench_pipeline [DOCUMENT]              everything above
 *   bench_pipeline --run ingest|cjson N DOCUMENT
 *                                          N documents only (what callgrind runs)
 */
#define _GNU_SOURCE /* popen */
#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <modbus.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "framer.h"
#include "log.h"
#include "mb_request.h"
#include "regmap.h"
#include "status.h"

#define ROUNDS 15
#define VARIANTS 16
#define READ_BUF_SIZE 16384 /* struct robot_link's read_buf */
/* The two run lengths under callgrind: their difference is what counts. */
#define COUNT_SHORT 64
#define COUNT_LONG 320

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

/* ---- the documents ---- */

struct document {
    char *text;
    size_t size;
};

/* Moves every number of 'array' by about 'delta', each element its own way. */
static void move_numbers(cJSON *array, double delta)
{
    double i = 0;
    for (cJSON *c = array ? array->child : NULL; c; c = c->next, i++)
        if (cJSON_IsNumber(c))
            cJSON_SetNumberValue(c, c->valuedouble + delta * (1 + 0.37 * i));
}

static cJSON *array_item(cJSON *node, int i)
{
    return cJSON_IsArray(node) ? cJSON_GetArrayItem(node, i) : NULL;
}

/*
 * What moves from one document to the next while the robot moves:
 * positions and velocities, the joints' monitor data, the cabinet's
 * figures, the torque sensor's readings, the TCP speed.
 */
static void move_robot(cJSON *root, unsigned step)
{
    static const char *const vectors[] = {"joint_actual_position", "joint_position",
                                          "actual_position", "position", "instVel"};
    double delta = 0.0123456789 * sin(0.3 * step) + 0.001 * step;

    for (size_t i = 0; i < sizeof(vectors) / sizeof(vectors[0]); i++)
        move_numbers(cJSON_GetObjectItemCaseSensitive(root, vectors[i]), delta);
    cJSON *monitor = cJSON_GetObjectItemCaseSensitive(root, "monitor_data");
    for (int i = 2; i <= 4; i++) {
        cJSON *n = array_item(monitor, i);
        if (cJSON_IsNumber(n))
            cJSON_SetNumberValue(n, n->valuedouble + delta);
    }
    cJSON *joints = array_item(monitor, 5);
    for (cJSON *j = joints ? joints->child : NULL; j; j = j->next)
        move_numbers(j, delta);
    cJSON *torque = array_item(cJSON_GetObjectItemCaseSensitive(root, "torqsensor"), 1);
    move_numbers(array_item(torque, 2), delta);
    move_numbers(array_item(torque, 3), delta);
    cJSON *speed = cJSON_GetObjectItemCaseSensitive(root, "curr_tcp_trans_vel");
    if (cJSON_IsNumber(speed))
        cJSON_SetNumberValue(speed, fabs(delta) * 100);
}

/* cJSON's compact text with a space after ',' and ':' outside strings, as
 * the controller writes it. */
static char *print_spaced(const cJSON *root)
{
    char *compact = cJSON_PrintUnformatted(root);
    if (!compact)
        return NULL;
    size_t n = strlen(compact);
    char *out = malloc(2 * n + 1), *o = out;
    bool in_string = false, escaped = false;
    for (size_t i = 0; out && i < n; i++) {
        char c = compact[i];
        *o++ = c;
        if (in_string) {
            in_string = escaped || c != '"';
            escaped = !escaped && c == '\\';
        } else if (c == '"') {
            in_string = true;
        } else if (c == ',' || c == ':') {
            *o++ = ' ';
        }
    }
    if (out)
        *o = '\0';
    cJSON_free(compact);
    return out;
}

/* Variant 'step' of the document, its "len" set to its own size. */
static int make_variant(const char *text, size_t size, unsigned step, struct document *out)
{
    cJSON *root = cJSON_ParseWithLength(text, size);
    if (!root)
        return -EINVAL;
    move_robot(root, step);
    out->text = NULL;
    /* The size's digits are part of the size: settle in a few rounds. */
    for (int round = 0; round < 4; round++) {
        cJSON *len = cJSON_GetObjectItemCaseSensitive(root, "len");
        if (len && out->text)
            cJSON_SetNumberValue(len, (double)out->size);
        else if (len)
            cJSON_SetNumberValue(len, (double)size);
        free(out->text);
        out->text = print_spaced(root);
        if (!out->text)
            break;
        out->size = strlen(out->text);
        if (!len || len->valuedouble == (double)out->size)
            break;
    }
    cJSON_Delete(root);
    return out->text ? 0 : -ENOMEM;
}

/* ---- the ingest path, as the gateway runs it ---- */

struct ingest {
    struct document docs[VARIANTS];
    int pair[2]; /* the robot's end [0], the gateway's [1] */
    char read_buf[READ_BUF_SIZE];
    struct framer framer;
    struct jaka_status buffers[2], *status, *scratch;
    struct regmap map;
    struct regmap_image img;
    unsigned objects, parse_errors;
};

/* gateway.c's on_status_document, less the counters and the clock. */
static void on_object(void *user, enum framer_event ev, const char *data, size_t size)
{
    struct ingest *in = user;
    if (ev != FRAMER_EVENT_OBJECT)
        return;
    in->objects++;
    if (status_parse(in->scratch, data, size) != STATUS_PARSE_OK) {
        in->parse_errors++;
        return;
    }
    struct jaka_status *previous = in->status;
    in->status = in->scratch;
    in->scratch = previous;
    regmap_encode_status(&in->img, in->status);
}

static void send_document(struct ingest *in, const struct document *d)
{
    size_t off = 0;
    while (off < d->size) {
        ssize_t n = send(in->pair[0], d->text + off, d->size - off, 0);
        if (n <= 0)
            abort();
        off += (size_t)n;
    }
}

/* Reads what is waiting, as on_read() does, and frames it. */
static void receive_all(struct ingest *in, size_t size)
{
    while (size > 0) {
        ssize_t n = read(in->pair[1], in->read_buf, sizeof(in->read_buf));
        if (n <= 0)
            abort();
        framer_feed(&in->framer, in->read_buf, (size_t)n);
        size -= (size_t)n;
    }
}

/* What callgrind counts: keep its name in sync with --toggle-collect. */
__attribute__((noinline)) void bench_ingest_documents(struct ingest *in, unsigned count);
__attribute__((noinline)) void bench_ingest_documents(struct ingest *in, unsigned count)
{
    for (unsigned i = 0; i < count; i++) {
        const struct document *d = &in->docs[i % VARIANTS];
        send_document(in, d);
        receive_all(in, d->size);
    }
}

__attribute__((noinline)) void bench_cjson_documents(struct ingest *in, unsigned count);
__attribute__((noinline)) void bench_cjson_documents(struct ingest *in, unsigned count)
{
    for (unsigned i = 0; i < count; i++) {
        const struct document *d = &in->docs[i % VARIANTS];
        cJSON_Delete(cJSON_ParseWithLength(d->text, d->size));
    }
}

static int ingest_init(struct ingest *in, const char *text, size_t size)
{
    for (unsigned v = 0; v < VARIANTS; v++)
        if (make_variant(text, size, v, &in->docs[v]) != 0)
            return -EINVAL;
    /* Big enough buffers that one document always fits in one send(). */
    int sndbuf = 1 << 20;
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, in->pair) < 0 ||
        setsockopt(in->pair[0], SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof(sndbuf)) < 0)
        return -errno;
    in->status = &in->buffers[0];
    in->scratch = &in->buffers[1];
    if (regmap_init(&in->map) || regmap_image_init(&in->img, &in->map, REGMAP_HIGH_WORD_FIRST) ||
        framer_init(&in->framer, FRAMER_DEFAULT_MAX_OBJECT, on_object, in))
        return -ENOMEM;
    regmap_encode_status(&in->img, in->status);
    return 0;
}

static void ingest_free(struct ingest *in)
{
    framer_free(&in->framer);
    regmap_image_free(&in->img);
    regmap_free(&in->map);
    close(in->pair[0]);
    close(in->pair[1]);
    for (unsigned v = 0; v < VARIANTS; v++)
        free(in->docs[v].text);
}

/* ---- time ---- */

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

static void time_cjson(void *p)
{
    bench_cjson_documents(p, VARIANTS);
}

static void time_ingest(void *p)
{
    bench_ingest_documents(p, VARIANTS);
}

/* ---- instructions ---- */

/* Total instructions callgrind counted in 'fn' for 'count' documents, or -1. */
static double callgrind_count(const char *self, const char *doc_path, const char *mode,
                              const char *fn, unsigned count, const char *out_file)
{
    char cmd[4096], line[512];
    double total = -1;

    snprintf(cmd, sizeof(cmd),
             "valgrind --tool=callgrind --callgrind-out-file='%s' --toggle-collect='%s' "
             "'%s' --run %s %u '%s' 2>/dev/null >/dev/null",
             out_file, fn, self, mode, count, doc_path);
    if (system(cmd) != 0)
        return -1;
    FILE *f = fopen(out_file, "r");
    if (!f)
        return -1;
    while (fgets(line, sizeof(line), f))
        if (strncmp(line, "totals:", 7) == 0 || strncmp(line, "summary:", 8) == 0)
            total = strtod(line + (line[0] == 't' ? 7 : 8), NULL);
    fclose(f);
    return total;
}

/*
 * Prints one line of callgrind_annotate's table ("1,234,567 (12.34%)
 * file:function [object]") as instructions per document, share, function
 * and the object's file name. Returns false for any other line.
 */
static bool print_profile_line(const char *line, double documents)
{
    char digits[32], share[16], location[512], object[512] = "";
    size_t k = 0;
    const char *p = line;

    for (; *p == ' ' || *p == ',' || (*p >= '0' && *p <= '9'); p++)
        if (*p >= '0' && *p <= '9' && k + 1 < sizeof(digits))
            digits[k++] = *p;
    digits[k] = '\0';
    if (k == 0 || sscanf(p, "(%15[^)]) %511s [%511[^]]]", share, location, object) < 2)
        return false;
    const char *function = strrchr(location, ':');
    const char *file = strrchr(object, '/');
    printf("    %9.0f  %7s  %-36s %s\n", strtod(digits, NULL) / documents, share,
           function ? function + 1 : location, file ? file + 1 : object);
    return true;
}

/* The ten functions with the most self instructions in a callgrind file. */
static void print_top_ten(const char *out_file, double documents)
{
    char cmd[1024], line[1024];
    int shown = 0;
    bool table = false;

    snprintf(cmd, sizeof(cmd), "callgrind_annotate --inclusive=no '%s' 2>/dev/null", out_file);
    FILE *p = popen(cmd, "r");
    if (!p)
        return;
    while (shown < 10 && fgets(line, sizeof(line), p)) {
        if (!table)
            table = strstr(line, "file:function") != NULL;
        else if (print_profile_line(line, documents))
            shown++;
    }
    pclose(p);
}

static void report_instructions(const char *self, const char *doc_path)
{
    char dir[] = "/tmp/bench_pipeline-XXXXXX";
    char files[4][64];
    double n[4];
    const unsigned counts[2] = {COUNT_SHORT, COUNT_LONG};

    if (system("command -v valgrind >/dev/null && command -v callgrind_annotate >/dev/null") != 0) {
        printf("instructions: valgrind is not installed (make deps), not counted\n");
        return;
    }
    if (!mkdtemp(dir)) {
        printf("instructions: mkdtemp: %s\n", strerror(errno));
        return;
    }
    for (int i = 0; i < 4; i++) {
        bool cjson = i < 2;
        snprintf(files[i], sizeof(files[i]), "%s/%s-%u", dir, cjson ? "cjson" : "ingest",
                 counts[i % 2]);
        n[i] = callgrind_count(self, doc_path, cjson ? "cjson" : "ingest",
                               cjson ? "bench_cjson_documents" : "bench_ingest_documents",
                               counts[i % 2], files[i]);
    }
    if (n[0] < 0 || n[1] < 0 || n[2] < 0 || n[3] < 0) {
        printf("instructions: a callgrind run failed\n");
    } else {
        double span = COUNT_LONG - COUNT_SHORT;
        double ref = (n[1] - n[0]) / span, ingest = (n[3] - n[2]) / span;
        printf("instructions per document (callgrind; runs of %d and %d documents, "
               "the difference)\n",
               COUNT_SHORT, COUNT_LONG);
        printf("  reference  cJSON_ParseWithLength + cJSON_Delete %10.0f  1.00\n", ref);
        printf("  ingest     read, frame, parse, swap, encode     %10.0f  %.2f  (target <= 0.85)\n",
               ingest, ingest / ref);
        printf("  top ten functions of the ingest run, self instructions per document:\n");
        print_top_ten(files[3], COUNT_LONG);
    }
    for (int i = 0; i < 4; i++)
        unlink(files[i]);
    rmdir(dir);
}

/* ---- a Modbus read ---- */

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

static int bench_modbus_read(struct regmap_image *img)
{
    static struct mb_ctx m;
    if (socketpair(AF_UNIX, SOCK_SEQPACKET, 0, m.pair) < 0)
        return -1;
    m.ctx = modbus_new_tcp(NULL, 0);
    modbus_set_socket(m.ctx, m.pair[0]);
    m.img = img;
    const uint8_t req[12] = {0, 1, 0, 0, 0, 6, 1, 4, 0x00, 0xC8, 0x00, 125};
    memcpy(m.req, req, sizeof(req));
    m.rsp_size = 9 + 250; /* the same reply size: 125 registers */
    int iters = 2000;
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
    return 0;
}

/* ---- main ---- */

static char *read_document(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    static char buf[1 << 20];

    if (!f) {
        fprintf(stderr, "bench: cannot open %s: %s\n", path, strerror(errno));
        return NULL;
    }
    *size = fread(buf, 1, sizeof(buf), f);
    fclose(f);
    while (*size && (buf[*size - 1] == '\n' || buf[*size - 1] == '\r'))
        (*size)--;
    return buf;
}

/* --run MODE N: only the documents, for callgrind to count. */
static int run_only(struct ingest *in, const char *mode, unsigned count)
{
    if (strcmp(mode, "ingest") == 0)
        bench_ingest_documents(in, count);
    else if (strcmp(mode, "cjson") == 0)
        bench_cjson_documents(in, count);
    else
        return 2;
    return strcmp(mode, "ingest") == 0 && (in->objects != count || in->parse_errors) ? 1 : 0;
}

int main(int argc, char **argv)
{
    const char *path = "tests/data/status-controller-a.json";
    const char *mode = NULL;
    unsigned count = 0;
    static struct ingest in;
    size_t size;

    if (argc == 5 && strcmp(argv[1], "--run") == 0) {
        mode = argv[2];
        count = (unsigned)strtoul(argv[3], NULL, 10);
        path = argv[4];
    } else if (argc == 2) {
        path = argv[1];
    } else if (argc != 1) {
        fprintf(stderr, "usage: bench_pipeline [DOCUMENT] | --run ingest|cjson N DOCUMENT\n");
        return 2;
    }
    char *text = read_document(path, &size);
    if (!text)
        return 1;
    if (ingest_init(&in, text, size) != 0) {
        fprintf(stderr, "bench: %s: cannot make its variants\n", path);
        return 1;
    }
    if (mode) {
        int rc = run_only(&in, mode, count);
        ingest_free(&in);
        return rc;
    }

    size_t total = 0;
    for (unsigned v = 0; v < VARIANTS; v++)
        total += in.docs[v].size;
    printf("status documents: %u variants of %s (%zu bytes), %zu bytes on average\n", VARIANTS,
           path, size, total / VARIANTS);
    report_instructions(argv[0], path);
    int iters = 10;
    struct result ref = measure(time_cjson, time_cjson, &in, iters);
    struct result all = measure(time_cjson, time_ingest, &in, iters);
    printf("time per document, medians of %d rounds of %d x %d documents\n", ROUNDS, iters,
           VARIANTS);
    printf("  reference  cJSON parse + delete         %8.1f us  1.00\n", ref.ns / VARIANTS / 1000);
    printf("  ingest     read to encoded registers    %8.1f us  %.2f  (%.1f%% of an 8 ms period)\n",
           all.ns / VARIANTS / 1000, all.ratio, all.ns / VARIANTS / 80000.0);
    if (in.parse_errors || in.objects == 0) {
        fprintf(stderr, "bench: %u of the documents did not parse\n", in.parse_errors);
        return 1;
    }
    int rc = bench_modbus_read(&in.img);
    ingest_free(&in);
    return rc ? 1 : 0;
}
