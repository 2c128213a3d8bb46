/* SPDX-License-Identifier: MIT */
/*
 * bench_modbus.c - jakagw as a Modbus TCP server, measured against a
 * reference slave built on plain libmodbus (bench/ref_slave.c) in the same
 * run, with the same load generator, both over loopback TCP:
 *
 *   - round trip p50/p99, one client, of FC03 and FC04 reads of 1, 10 and
 *     125 registers, samples of every kind and server interleaved one by
 *     one; a second jakagw, with no robot, shows what the stream adds;
 *   - throughput, closed loop (one request in flight per client), at 1, 8
 *     and 32 clients, and the server's CPU per request from /proc/PID/stat
 *     (utime + stime); jakagw's idle cost (the status stream alone, timed
 *     in windows with no client between the loaded ones) is subtracted;
 *   - jakagw's CPU with jakasim streaming at 125 Hz and no client, per
 *     document and as a ratio to cJSON's parse and free of the same
 *     document timed here;
 *   - jakagw's peak RSS (VmHWM) after the loaded windows, and its RSS
 *     along a stream of a million documents fed as fast as it takes them.
 *
 * jakasim streams at 125 Hz (--period-ms 8) into the jakagw under load;
 * the reference has no stream to take, so every figure of jakagw includes
 * what the stream costs it. The machine may be shared and noisy: each
 * figure is a median over interleaved rounds, and the ratios are what to
 * compare across runs.
 *
 * The load generator and jakasim run on one CPU, the servers on another
 * (--cpus GENERATOR,SERVER; "none" leaves placement to the scheduler):
 * both servers are then woken from another CPU, as by a client on another
 * host. Left to the scheduler, whether a server happened to share the
 * generator's CPU moved its p50 2.5-fold from one run to the next.
 *
 *   bench_modbus [--jakagw PATH] [--jakasim PATH] [--ref-slave PATH]
 *                [--document FILE] [--documents N] [--rounds N]
 *                [--cpus G,S|none]
 *   bench_modbus --load PORT,CLIENTS,SECONDS [--cpus G,S|none]
 *                only the closed-loop load against a server already
 *                running on 127.0.0.1:PORT, to profile it (perf, strace)
 *
 * The binaries default to the build directory this program sits in
 * (BUILD/bench/bench_modbus: BUILD/jakagw, BUILD/jakasim,
 * BUILD/bench/ref_slave). Every child is stopped by its pid.
 */
#include "bench_proc.h"

#include <cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "regmap.h"

#define LAT_ROUNDS 9
#define LAT_SAMPLES 2000  /* per kind, server and round */
#define TP_WINDOW_S 1.0   /* one loaded window */
#define IDLE_WINDOW_S 2.0 /* one window with no client */
#define MAX_CLIENTS 32
#define DEFAULT_DOCUMENTS 1000000
#define RSS_CHECKPOINTS 10

/* GW_QUIET, a jakagw with no robot, takes part in the round trips only:
 * it shows what the stream costs jakagw's round trips. */
enum server { GW, REF, SERVERS, GW_QUIET = SERVERS, LAT_SERVERS };

static const struct kind {
    uint8_t function;
    uint16_t count;
} kinds[] = {{3, 1}, {3, 10}, {3, 125}, {4, 1}, {4, 10}, {4, 125}};
#define KINDS (sizeof(kinds) / sizeof(kinds[0]))

static const unsigned client_counts[] = {1, 8, 32};
#define CLIENT_COUNTS (sizeof(client_counts) / sizeof(client_counts[0]))

/* CPUs: the load generator and jakasim on one, the servers on the other
 * (-1: wherever the scheduler puts them). */
static int generator_cpu = -1, server_cpu = -1;

/* ---- the Modbus client (sockets and requests: bench_proc.h) ---- */

struct conn {
    int fd;
    uint16_t tid;
    unsigned next_kind; /* throughput: the kinds in turn */
    uint8_t rsp[9 + 250];
    size_t got;
};

static size_t reply_size(const struct kind *k)
{
    return 9 + 2u * k->count;
}

static void send_read(struct conn *c, uint8_t function, uint16_t address, uint16_t count)
{
    modbus_tcp_send(c->fd, ++c->tid, function, address, count);
}

static void check_reply(const struct conn *c, uint8_t function, uint16_t count)
{
    unsigned tid = (unsigned)c->rsp[0] << 8 | c->rsp[1];
    if (tid != c->tid || c->rsp[7] != function || c->rsp[8] != 2 * count)
        die("bad reply to function %u of %u registers: tid %u/%u, function %u, %u bytes", function,
            count, tid, c->tid, c->rsp[7], c->rsp[8]);
}

static void read_regs(struct conn *c, uint8_t function, uint16_t address, uint16_t count)
{
    send_read(c, function, address, count);
    recv_exact(c->fd, c->rsp, 9 + 2u * count);
    check_reply(c, function, count);
}

static double round_trip_us(struct conn *c, const struct kind *k)
{
    double t0 = now_s();
    read_regs(c, k->function, 0, k->count);
    return (now_s() - t0) * 1e6;
}

static uint32_t documents_parsed(struct conn *c)
{
    read_regs(c, 4, 20, 2); /* input register 20: documents_parsed, u32 */
    return (uint32_t)c->rsp[9] << 24 | (uint32_t)c->rsp[10] << 16 | (uint32_t)c->rsp[11] << 8 |
           c->rsp[12];
}

/* ---- the servers ---- */

struct servers {
    const char *jakagw, *jakasim, *ref_slave;
    char conf[PATH_MAX + 16];
    uint16_t status_port, command_port, modbus_port[LAT_SERVERS];
    pid_t sim, pid[LAT_SERVERS];
};

/* Room for the loaded clients, the latency client and the poller. */
static void write_config(struct servers *s)
{
    write_jakagw_config(s->conf, sizeof(s->conf), MAX_CLIENTS + 4, "");
}

static pid_t start_jakagw(struct servers *s, const char *name, uint16_t status_port,
                          uint16_t modbus_port)
{
    return spawn_jakagw(name, s->jakagw, s->conf, status_port, s->command_port, modbus_port,
                        server_cpu);
}

static void start_servers(struct servers *s, const struct regmap *map)
{
    char sp[8], cp[8], rp[8], sizes[REGMAP_TABLE_COUNT][8];

    write_config(s);
    s->status_port = free_port();
    s->command_port = free_port();
    snprintf(sp, sizeof(sp), "%u", s->status_port);
    snprintf(cp, sizeof(cp), "%u", s->command_port);
    char *sim_argv[] = {
        (char *)s->jakasim, "--status-port", sp, "--command-port", cp, "--period-ms", "8", NULL};
    s->sim = spawn("jakasim", sim_argv, generator_cpu);
    wait_listening(s->status_port, s->sim, "jakasim");
    wait_listening(s->command_port, s->sim, "jakasim");

    s->modbus_port[GW] = free_port();
    s->pid[GW] = start_jakagw(s, "jakagw", s->status_port, s->modbus_port[GW]);

    /* The reference's mapping has the sizes of jakagw's image. */
    for (int t = 0; t < REGMAP_TABLE_COUNT; t++)
        snprintf(sizes[t], sizeof(sizes[t]), "%u", map->size[t]);
    s->modbus_port[REF] = free_port();
    snprintf(rp, sizeof(rp), "%u", s->modbus_port[REF]);
    char *ref_argv[] = {(char *)s->ref_slave,
                        "--bind",
                        "127.0.0.1",
                        "--port",
                        rp,
                        "--bits",
                        sizes[REGMAP_COIL],
                        "--input-bits",
                        sizes[REGMAP_DISCRETE_INPUT],
                        "--registers",
                        sizes[REGMAP_HOLDING_REGISTER],
                        "--input-registers",
                        sizes[REGMAP_INPUT_REGISTER],
                        NULL};
    s->pid[REF] = spawn("ref_slave", ref_argv, server_cpu);
    wait_listening(s->modbus_port[REF], s->pid[REF], "ref_slave");

    /* Its status port is one nobody listens on: it only retries, at most
     * every reconnect_max_ms. */
    s->modbus_port[GW_QUIET] = free_port();
    s->pid[GW_QUIET] = start_jakagw(s, "jakagw-quiet", free_port(), s->modbus_port[GW_QUIET]);
}

/* Waits until jakagw has taken 'count' more documents than 'from'. */
static uint32_t wait_documents(struct conn *c, uint32_t from, uint32_t count, double timeout_s)
{
    double deadline = now_s() + timeout_s;
    uint32_t n;
    while ((n = documents_parsed(c)) - from < count) {
        if (now_s() > deadline)
            die("jakagw took %u documents in %.0f s, expected %u", n - from, timeout_s, count);
        sleep_s(0.005);
    }
    return n;
}

/* ---- round trips ---- */

struct latency {
    double p50[LAT_SERVERS][KINDS], p99[LAT_SERVERS][KINDS];
    /* Medians of the per-round ratios to the reference. */
    double p50_ratio[LAT_SERVERS][KINDS], p99_ratio[LAT_SERVERS][KINDS];
};

static void measure_latency(struct servers *s, struct latency *out)
{
    static double samples[LAT_SERVERS][KINDS][LAT_SAMPLES];
    double p50[LAT_ROUNDS][LAT_SERVERS][KINDS], p99[LAT_ROUNDS][LAT_SERVERS][KINDS];
    struct conn conn[LAT_SERVERS] = {{0}};

    for (int v = 0; v < LAT_SERVERS; v++)
        conn[v].fd = connect_loopback(s->modbus_port[v]);
    for (unsigned i = 0; i < 200; i++) /* warm up */
        for (int v = 0; v < LAT_SERVERS; v++)
            round_trip_us(&conn[v], &kinds[i % KINDS]);
    for (unsigned r = 0; r < LAT_ROUNDS; r++) {
        for (unsigned i = 0; i < LAT_SAMPLES; i++)
            for (unsigned k = 0; k < KINDS; k++)
                for (int j = 0; j < LAT_SERVERS; j++) {
                    int v = (int)((i + k + j) % LAT_SERVERS); /* each goes first in turn */
                    samples[v][k][i] = round_trip_us(&conn[v], &kinds[k]);
                }
        for (int v = 0; v < LAT_SERVERS; v++)
            for (unsigned k = 0; k < KINDS; k++) {
                p50[r][v][k] = percentile(samples[v][k], LAT_SAMPLES, 0.50);
                p99[r][v][k] = percentile(samples[v][k], LAT_SAMPLES, 0.99);
            }
    }
    for (unsigned k = 0; k < KINDS; k++) {
        double a[LAT_ROUNDS], b[LAT_ROUNDS];
        for (int v = 0; v < LAT_SERVERS; v++) {
            for (unsigned r = 0; r < LAT_ROUNDS; r++) {
                a[r] = p50[r][v][k];
                b[r] = p99[r][v][k];
            }
            out->p50[v][k] = median(a, LAT_ROUNDS);
            out->p99[v][k] = median(b, LAT_ROUNDS);
        }
        for (int v = 0; v < LAT_SERVERS; v++) {
            for (unsigned r = 0; r < LAT_ROUNDS; r++) {
                a[r] = p50[r][v][k] / p50[r][REF][k];
                b[r] = p99[r][v][k] / p99[r][REF][k];
            }
            out->p50_ratio[v][k] = median(a, LAT_ROUNDS);
            out->p99_ratio[v][k] = median(b, LAT_ROUNDS);
        }
    }
    for (int v = 0; v < LAT_SERVERS; v++)
        close(conn[v].fd);
}

/* ---- closed-loop throughput ---- */

struct window {
    double seconds, cpu_s;
    uint64_t requests;
};

static void send_next(struct conn *c)
{
    const struct kind *k = &kinds[c->next_kind];
    c->got = 0;
    send_read(c, k->function, 0, k->count);
}

/*
 * 'n' clients, one request in flight each, for 'seconds'; the server's
 * CPU is read before the first request and after the last reply.
 */
/* 'server' 0: no CPU figure (--load, a server we did not start). */
static struct window closed_loop(struct conn *conns, unsigned n, pid_t server, double seconds)
{
    struct epoll_event ev, events[MAX_CLIENTS];
    int ep = epoll_create1(EPOLL_CLOEXEC);
    unsigned in_flight = 0;
    struct window w = {0};

    if (ep < 0)
        die("epoll_create1: %s", strerror(errno));
    for (unsigned i = 0; i < n; i++) {
        ev.events = EPOLLIN;
        ev.data.ptr = &conns[i];
        if (epoll_ctl(ep, EPOLL_CTL_ADD, conns[i].fd, &ev) < 0)
            die("epoll_ctl: %s", strerror(errno));
    }
    double cpu0 = server ? cpu_seconds(server) : 0, t0 = now_s(), end = t0 + seconds;
    for (unsigned i = 0; i < n; i++, in_flight++)
        send_next(&conns[i]);
    bool sending = true;
    while (in_flight > 0) {
        int ready = epoll_wait(ep, events, MAX_CLIENTS, BENCH_IO_TIMEOUT_S * 1000);
        if (ready < 0 && errno == EINTR)
            continue;
        if (ready <= 0)
            die("no reply within %d s", BENCH_IO_TIMEOUT_S);
        if (sending && now_s() >= end)
            sending = false;
        for (int e = 0; e < ready; e++) {
            struct conn *c = events[e].data.ptr;
            const struct kind *k = &kinds[c->next_kind];
            ssize_t got = recv(c->fd, c->rsp + c->got, reply_size(k) - c->got, 0);
            if (got <= 0)
                die("recv: %s", got < 0 ? strerror(errno) : "connection closed");
            c->got += (size_t)got;
            if (c->got < reply_size(k))
                continue;
            check_reply(c, k->function, k->count);
            w.requests++;
            c->next_kind = (c->next_kind + 1) % KINDS;
            if (sending)
                send_next(c);
            else
                in_flight--;
        }
    }
    w.seconds = now_s() - t0;
    w.cpu_s = server ? cpu_seconds(server) - cpu0 : 0;
    close(ep);
    return w;
}

struct throughput {
    double idle_cpu_share; /* jakagw, no client: CPU seconds per second */
    double idle_seconds;
    uint32_t idle_documents;                    /* taken in the windows with no client */
    double rate[SERVERS][CLIENT_COUNTS];        /* median requests per second */
    double rate_ratio[CLIENT_COUNTS];           /* median of per-round ratios */
    double cpu_per_req[SERVERS][CLIENT_COUNTS]; /* us, jakagw's idle cost removed */
    long hwm_kib;
};

static void measure_throughput(struct servers *s, unsigned rounds, struct conn *poller,
                               struct throughput *out)
{
    static struct conn conns[SERVERS][MAX_CLIENTS];
    double rates[SERVERS][CLIENT_COUNTS][16], ratios[CLIENT_COUNTS][16];
    struct window total[SERVERS][CLIENT_COUNTS] = {{{0}}};
    double idle_cpu = 0, idle_time = 0;

    out->idle_documents = 0;
    for (int v = 0; v < SERVERS; v++)
        for (unsigned i = 0; i < MAX_CLIENTS; i++) {
            conns[v][i].fd = connect_loopback(s->modbus_port[v]);
            conns[v][i].next_kind = i % KINDS;
        }
    for (int v = 0; v < SERVERS; v++) /* warm up: every connection served once */
        closed_loop(conns[v], MAX_CLIENTS, s->pid[v], TP_WINDOW_S);
    for (unsigned r = 0; r < rounds; r++) {
        uint32_t d0 = documents_parsed(poller);
        double c0 = cpu_seconds(s->pid[GW]), t0 = now_s();
        sleep_s(IDLE_WINDOW_S);
        idle_cpu += cpu_seconds(s->pid[GW]) - c0;
        idle_time += now_s() - t0;
        out->idle_documents += documents_parsed(poller) - d0;
        for (unsigned n = 0; n < CLIENT_COUNTS; n++) {
            struct window w[SERVERS];
            for (int j = 0; j < SERVERS; j++) {
                int v = (int)((r + n + j) % SERVERS); /* either goes first */
                w[v] = closed_loop(conns[v], client_counts[n], s->pid[v], TP_WINDOW_S);
                rates[v][n][r] = (double)w[v].requests / w[v].seconds;
                total[v][n].seconds += w[v].seconds;
                total[v][n].cpu_s += w[v].cpu_s;
                total[v][n].requests += w[v].requests;
            }
            ratios[n][r] = rates[GW][n][r] / rates[REF][n][r];
        }
    }
    out->hwm_kib = status_kib(s->pid[GW], "VmHWM:");
    out->idle_cpu_share = idle_cpu / idle_time;
    out->idle_seconds = idle_time;
    for (unsigned n = 0; n < CLIENT_COUNTS; n++) {
        for (int v = 0; v < SERVERS; v++) {
            const struct window *t = &total[v][n];
            double cpu = t->cpu_s - (v == GW ? out->idle_cpu_share * t->seconds : 0);
            out->rate[v][n] = median(rates[v][n], rounds);
            out->cpu_per_req[v][n] = cpu / (double)t->requests * 1e6;
        }
        out->rate_ratio[n] = median(ratios[n], rounds);
    }
    for (int v = 0; v < SERVERS; v++)
        for (unsigned i = 0; i < MAX_CLIENTS; i++)
            close(conns[v][i].fd);
}

/* ---- documents ---- */

/* The file, without a trailing newline; freed by the caller. */
static char *read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    size_t cap = 1 << 20;
    char *buf = malloc(cap);

    if (!f || !buf)
        die("%s: %s", path, strerror(errno));
    *size = fread(buf, 1, cap, f);
    fclose(f);
    while (*size && (buf[*size - 1] == '\n' || buf[*size - 1] == '\r'))
        (*size)--;
    return buf;
}

/* Median time of cJSON's parse and free of a document, in us. */
static double cjson_us(const char *doc, size_t size)
{
    double t[15];
    for (unsigned r = 0; r < 15; r++) {
        double t0 = now_s();
        for (unsigned i = 0; i < 200; i++)
            cJSON_Delete(cJSON_ParseWithLength(doc, size));
        t[r] = (now_s() - t0) / 200 * 1e6;
    }
    return median(t, 15);
}

struct ingest {
    uint32_t documents, measured; /* all, and those after the warm-up */
    double seconds, cpu_s;
    long rss_first_kib, rss_max_kib, rss_last_kib, hwm_kib;
    long data_first_kib, data_last_kib; /* VmData: all the memory asked for */
    long rss_kib[RSS_CHECKPOINTS + 1];  /* at each checkpoint, 1.. */
    double doc_cjson_us;
    size_t doc_size;
};

/*
 * A second jakagw whose status port is ours: the document is written back
 * to back as fast as jakagw takes it (the socket's buffer paces us), and
 * RSS is read at checkpoints. Commands still go to jakasim.
 *
 * Every other document has its "rapidrate" changed (its first digit): the
 * status link keeps only the newest of several documents waiting and
 * drops the others unparsed, unless one changes a member the events log
 * or the motion tracker follows (status.h, STATUS_MARK_MEMBERS). So each
 * document fed is parsed, as each was before that rule, and counted in
 * documents_parsed.
 */
static void measure_ingest(struct servers *s, const char *doc, size_t size, uint32_t documents,
                           struct ingest *out)
{
    uint16_t status_port, modbus_port = free_port();
    int listener = listen_loopback(&status_port);
    pid_t pid = start_jakagw(s, "jakagw-feed", status_port, modbus_port);
    struct pollfd p = {.fd = listener, .events = POLLIN};
    static char batch[65 * 9000];
    /* One document more than a batch sends: a batch starts at the
     * document or at its variant, as the last one sent asks. */
    unsigned per_batch = (unsigned)(sizeof(batch) / size) - 1;
    uint32_t step = documents / RSS_CHECKPOINTS, sent = 0;
    const char *rate = strstr(doc, "\"rapidrate\": ");
    size_t digit = rate ? (size_t)(rate - doc) + strlen("\"rapidrate\": ") : 0;

    if (per_batch == 0 || per_batch > 64 || step == 0)
        die("documents too large or too few");
    if (!rate || digit >= size || doc[digit] < '0' || doc[digit] > '9')
        die("the fed document has no numeric \"rapidrate\" to vary");
    for (unsigned i = 0; i <= per_batch; i++) {
        memcpy(batch + i * size, doc, size);
        if (i % 2)
            batch[i * size + digit] = doc[digit] == '1' ? '2' : '1';
    }
    if (poll(&p, 1, BENCH_IO_TIMEOUT_S * 1000) != 1)
        die("jakagw-feed did not connect to the status port");
    int feed = accept(listener, NULL, NULL);
    if (feed < 0)
        die("accept: %s", strerror(errno));
    set_timeouts(feed);
    struct conn poller = {.fd = connect_loopback(modbus_port)};
    uint32_t base = documents_parsed(&poller);

    out->documents = documents;
    out->rss_max_kib = 0;
    out->doc_size = size;
    double t0 = 0, c0 = 0;
    /* The first checkpoint ends a warm-up: the figures count from there. */
    for (unsigned cp = 1; cp <= RSS_CHECKPOINTS; cp++) {
        uint32_t target = cp == RSS_CHECKPOINTS ? documents : cp * step;
        while (sent < target) {
            unsigned n = target - sent < per_batch ? target - sent : per_batch;
            send_all(feed, batch + (sent % 2) * size, n * size);
            sent += n;
        }
        wait_documents(&poller, base, target, 60);
        long rss = status_kib(pid, "VmRSS:");
        out->rss_kib[cp] = rss;
        if (cp == 1) {
            out->measured = documents - target;
            out->rss_first_kib = rss;
            out->data_first_kib = status_kib(pid, "VmData:");
            t0 = now_s();
            c0 = cpu_seconds(pid);
        }
        if (rss > out->rss_max_kib)
            out->rss_max_kib = rss;
        out->rss_last_kib = rss;
    }
    out->seconds = now_s() - t0;
    out->cpu_s = cpu_seconds(pid) - c0;
    /* Input registers 22-25: parse_errors, framing_errors. Every document
     * fed must have been taken whole. */
    read_regs(&poller, 4, 22, 4);
    for (unsigned i = 0; i < 8; i++)
        if (poller.rsp[9 + i])
            die("jakagw-feed counted parse or framing errors: %s is not one document",
                "the fed document");
    out->hwm_kib = status_kib(pid, "VmHWM:");
    out->data_last_kib = status_kib(pid, "VmData:");
    close(poller.fd);
    close(feed);
    close(listener);
    stop_child(pid);
}

/* ---- the table ---- */

static const char *verdict(bool met)
{
    return met ? "met" : "NOT MET";
}

static void print_table(const struct latency *lat, const struct throughput *tp,
                        const struct ingest *ing, size_t stream_doc_size, double stream_cjson_us,
                        unsigned rounds, const char *doc_path)
{
    bool p50_ok = true, p99_ok = true, rate_ok = true, cpu_ok = true;

    printf("Modbus over loopback TCP: jakagw (jakasim streaming into it at 125 Hz) "
           "vs ref_slave\n(plain libmodbus, a select loop), the same load generator\n");
    printf("  round trip, 1 client, medians of %d rounds of %d\n"
           "                             jakagw  ref_slave  jakagw/ref  target"
           "   jakagw with no stream\n",
           LAT_ROUNDS, LAT_SAMPLES);
    for (unsigned k = 0; k < KINDS; k++) {
        char label[64];
        snprintf(label, sizeof(label), "FC%02u %3u registers", kinds[k].function, kinds[k].count);
        printf("  %-18s p50 %7.1f us %7.1f us  %5.2f    <= 1.10  %7.1f us  %5.2f\n", label,
               lat->p50[GW][k], lat->p50[REF][k], lat->p50_ratio[GW][k], lat->p50[GW_QUIET][k],
               lat->p50_ratio[GW_QUIET][k]);
        printf("  %-18s p99 %7.1f us %7.1f us  %5.2f    <= 1.00  %7.1f us  %5.2f\n", "",
               lat->p99[GW][k], lat->p99[REF][k], lat->p99_ratio[GW][k], lat->p99[GW_QUIET][k],
               lat->p99_ratio[GW_QUIET][k]);
        p50_ok &= lat->p50_ratio[GW][k] <= 1.10;
        p99_ok &= lat->p99_ratio[GW][k] <= 1.00;
    }
    printf("  throughput, closed loop, FC03/FC04 of 1/10/125 in turn, medians of %u rounds "
           "of %.0f s\n",
           rounds, TP_WINDOW_S);
    for (unsigned n = 0; n < CLIENT_COUNTS; n++) {
        printf("  %2u clients            %8.0f/s  %8.0f/s    %5.2f  (target >= 1.00)\n",
               client_counts[n], tp->rate[GW][n], tp->rate[REF][n], tp->rate_ratio[n]);
        rate_ok &= tp->rate_ratio[n] >= 1.0;
    }
    printf("  server CPU per request (utime+stime; jakagw's idle stream cost removed)\n");
    for (unsigned n = 0; n < CLIENT_COUNTS; n++) {
        double ratio = tp->cpu_per_req[GW][n] / tp->cpu_per_req[REF][n];
        printf("  %2u clients            %7.2f us  %7.2f us    %5.2f  (target <= 1.00)\n",
               client_counts[n], tp->cpu_per_req[GW][n], tp->cpu_per_req[REF][n], ratio);
        cpu_ok &= ratio <= 1.0;
    }

    double per_doc_us =
        tp->idle_documents ? tp->idle_cpu_share * tp->idle_seconds / tp->idle_documents * 1e6 : 0;
    printf("Status stream: jakagw, jakasim at 125 Hz, no client (%.0f s, %u documents)\n",
           tp->idle_seconds, tp->idle_documents);
    printf("  CPU                    %5.2f%% of a core                  (target < 1%%)\n",
           tp->idle_cpu_share * 100);
    printf("  per document           %6.1f us, %.2f x cJSON parse + free of it (%.1f us, "
           "%zu bytes)\n",
           per_doc_us, per_doc_us / stream_cjson_us, stream_cjson_us, stream_doc_size);
    printf("  fed as fast as taken   %6.1f us CPU per document, %.2f x cJSON parse + free, "
           "%.0f documents/s\n  (%s, %zu bytes)\n",
           ing->cpu_s / (ing->measured) * 1e6,
           ing->cpu_s / (ing->measured) * 1e6 / ing->doc_cjson_us, ing->measured / ing->seconds,
           doc_path, ing->doc_size);

    long growth = ing->rss_last_kib - ing->rss_first_kib;
    long data_growth = ing->data_last_kib - ing->data_first_kib;
    printf("Memory of jakagw                                   (target < 8 MiB, no growth)\n");
    printf("  peak RSS (VmHWM), 32 clients and the 125 Hz stream   %6ld KiB\n", tp->hwm_kib);
    printf("  fed %u documents: peak RSS %ld KiB; from the first tenth to the end, "
           "RSS %+ld KiB,\n  memory asked of the system (VmData) %+ld KiB; RSS at every "
           "tenth, KiB:",
           ing->documents, ing->hwm_kib, growth, data_growth);
    for (unsigned cp = 1; cp <= RSS_CHECKPOINTS; cp++)
        printf(" %ld", ing->rss_kib[cp]);
    printf("\n");
    /* Growth is memory asked for: RSS alone also counts pages of the same
     * heap touched for the first time. */
    bool mem_ok = tp->hwm_kib < 8192 && ing->hwm_kib < 8192 && data_growth <= 0;

    printf("Targets: throughput %s; CPU per request %s; p50 within 1.1x %s; p99 no worse "
           "%s;\n         stream CPU < 1%% %s; memory < 8 MiB and no growth %s\n",
           verdict(rate_ok), verdict(cpu_ok), verdict(p50_ok), verdict(p99_ok),
           verdict(tp->idle_cpu_share < 0.01), verdict(mem_ok));
}

/* --load: the closed loop alone, against a server someone else started. */
static int run_load(const char *spec)
{
    unsigned port, clients;
    double seconds;
    static struct conn conns[MAX_CLIENTS];

    if (sscanf(spec, "%u,%u,%lf", &port, &clients, &seconds) != 3 || port == 0 ||
        port > 65535 || clients == 0 || clients > MAX_CLIENTS || seconds <= 0) {
        fprintf(stderr, "bench_modbus: --load PORT,CLIENTS,SECONDS (CLIENTS 1..%d)\n",
                MAX_CLIENTS);
        return 2;
    }
    for (unsigned i = 0; i < clients; i++)
        conns[i].fd = connect_loopback((uint16_t)port);
    struct window w = closed_loop(conns, clients, 0, seconds);
    printf("%u clients: %llu requests in %.2f s, %.0f/s\n", clients,
           (unsigned long long)w.requests, w.seconds, (double)w.requests / w.seconds);
    for (unsigned i = 0; i < clients; i++)
        close(conns[i].fd);
    return 0;
}

/* ---- main ---- */

int main(int argc, char **argv)
{
    bench_name = "bench_modbus";
    struct servers s = {
        .jakagw = sibling(argv[0], "../jakagw"),
        .jakasim = sibling(argv[0], "../jakasim"),
        .ref_slave = sibling(argv[0], "ref_slave"),
    };
    const char *doc_path = "tests/data/status-controller-a.json";
    unsigned long documents = DEFAULT_DOCUMENTS, rounds = 7;
    const char *cpus = NULL, *load = NULL;
    struct regmap map;

    for (int i = 1; i < argc; i++) {
        const char *flag = argv[i], *value = i + 1 < argc ? argv[i + 1] : NULL;
        if (!value) {
            fprintf(stderr, "bench_modbus: %s needs a value\n", flag);
            return 2;
        }
        i++;
        if (strcmp(flag, "--jakagw") == 0)
            s.jakagw = value;
        else if (strcmp(flag, "--jakasim") == 0)
            s.jakasim = value;
        else if (strcmp(flag, "--ref-slave") == 0)
            s.ref_slave = value;
        else if (strcmp(flag, "--document") == 0)
            doc_path = value;
        else if (strcmp(flag, "--documents") == 0)
            documents = strtoul(value, NULL, 10);
        else if (strcmp(flag, "--rounds") == 0)
            rounds = strtoul(value, NULL, 10);
        else if (strcmp(flag, "--cpus") == 0)
            cpus = value;
        else if (strcmp(flag, "--load") == 0)
            load = value;
        else {
            fprintf(stderr, "bench_modbus: unknown option %s\n", flag);
            return 2;
        }
    }
    if (documents < 10 * RSS_CHECKPOINTS || documents > UINT32_MAX / 2 || rounds < 1 ||
        rounds > 16) {
        fprintf(stderr, "bench_modbus: --documents >= %d, --rounds 1..16\n", 10 * RSS_CHECKPOINTS);
        return 2;
    }
    if (access(s.ref_slave, X_OK) != 0) {
        fprintf(stderr, "bench_modbus: no reference slave at %s (make %s)\n", s.ref_slave,
                s.ref_slave);
        return 1;
    }
    if (!cpus) {
        cpu_set_t set;
        bool both = sched_getaffinity(0, sizeof(set), &set) == 0 && CPU_ISSET(0, &set) &&
                    CPU_ISSET(1, &set);
        cpus = both ? "0,1" : "none";
    }
    if (strcmp(cpus, "none") != 0 &&
        (sscanf(cpus, "%d,%d", &generator_cpu, &server_cpu) != 2 || generator_cpu < 0 ||
         server_cpu < 0 || generator_cpu >= CPU_SETSIZE || server_cpu >= CPU_SETSIZE)) {
        fprintf(stderr, "bench_modbus: --cpus: GENERATOR,SERVER (CPU numbers) or none\n");
        return 2;
    }
    pin_to(generator_cpu);
    signal(SIGPIPE, SIG_IGN);
    if (load)
        return run_load(load);
    signal(SIGINT, on_fatal_signal);
    signal(SIGTERM, on_fatal_signal);
    snprintf(bench_tmp_dir, sizeof(bench_tmp_dir), "/tmp/bench_modbus-XXXXXX");
    if (!mkdtemp(bench_tmp_dir))
        die("mkdtemp: %s", strerror(errno));
    if (regmap_init(&map) != 0)
        die("regmap_init failed");

    size_t doc_size;
    char *doc = read_file(doc_path, &doc_size);

    start_servers(&s, &map);
    struct conn poller = {.fd = connect_loopback(s.modbus_port[GW])};
    wait_documents(&poller, documents_parsed(&poller), 10, 10); /* the stream is live */

    struct latency lat;
    struct throughput tp;
    measure_latency(&s, &lat);
    stop_child(s.pid[GW_QUIET]);
    measure_throughput(&s, (unsigned)rounds, &poller, &tp);
    close(poller.fd);
    stop_child(s.pid[REF]);
    stop_child(s.pid[GW]);

    /* What cJSON alone pays for the document jakasim streams. */
    char sim_doc_path[PATH_MAX + 16], cmd[3 * PATH_MAX];
    snprintf(sim_doc_path, sizeof(sim_doc_path), "%s/jakasim.json", bench_tmp_dir);
    snprintf(cmd, sizeof(cmd), "'%s' --print-status > '%s'", s.jakasim, sim_doc_path);
    if (system(cmd) != 0)
        die("%s failed", cmd);
    size_t sim_doc_size;
    char *sim_doc = read_file(sim_doc_path, &sim_doc_size);
    double sim_cjson_us = cjson_us(sim_doc, sim_doc_size);
    free(sim_doc);

    struct ingest ing = {0};
    measure_ingest(&s, doc, doc_size, (uint32_t)documents, &ing);
    ing.doc_cjson_us = cjson_us(doc, doc_size);
    bench_end();
    regmap_free(&map);
    free(doc);

    print_table(&lat, &tp, &ing, sim_doc_size, sim_cjson_us, (unsigned)rounds, doc_path);
    return 0;
}
