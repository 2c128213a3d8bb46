/* SPDX-License-Identifier: MIT */
/*
 * bench_tls.c - Modbus/TCP Security (mbaps) against plain Modbus TCP, in
 * the same jakagw, in the same run:
 *
 *   - FC04 reads of 10 and 125 registers by one client in a closed loop
 *     (one request in flight), plain and TLS windows interleaved, several
 *     rounds: throughput, and the server's CPU per request from
 *     /proc/PID/stat with the cost of the status stream alone (jakasim at
 *     125 Hz, measured in windows with no client) taken off; the ratios
 *     TLS / plain, medians over the rounds (target: within 1.3x);
 *   - the full handshake (no session resumption), p50 and p99 in ms: from
 *     connect() to the client's handshake done, and to the first answer
 *     (the server verifies the client's certificate in between);
 *   - memory: RSS with 32 TLS clients connected (target: under 16 MiB),
 *     and what each costs, against 32 plain clients.
 *
 * The certificates are made by tests/tls/make-pki.sh, the commands of
 * docs/security.md. The machine may be shared and noisy: compare the
 * ratios, which are measured side by side.
 *
 *   bench_tls [--jakagw PATH] [--jakasim PATH] [--pki-script PATH] [--rounds N]
 */
#include "bench_proc.h"

#include <openssl/err.h>
#include <openssl/ssl.h>

#define WINDOW_S 0.5      /* one loaded window */
#define IDLE_WINDOW_S 1.0 /* one window with no client */
#define HANDSHAKES 200
#define MEMORY_CLIENTS 32

struct setup {
    const char *jakagw, *jakasim, *pki_script;
    char pki[PATH_MAX + 8];
    char conf[PATH_MAX + 16];
    uint16_t modbus_port, tls_port;
    pid_t gw;
    SSL_CTX *ssl;
};

/* A Modbus client, plain (ssl NULL) or TLS. */
struct client {
    int fd;
    SSL *ssl;
    uint16_t tid;
};

static void ssl_die(const char *what)
{
    char buf[256];
    ERR_error_string_n(ERR_get_error(), buf, sizeof(buf));
    die("%s: %s", what, buf);
}

static void io_write(struct client *c, const void *data, size_t size)
{
    if (!c->ssl) {
        send_all(c->fd, data, size);
        return;
    }
    if (SSL_write(c->ssl, data, (int)size) != (int)size)
        ssl_die("SSL_write");
}

static void io_read(struct client *c, void *data, size_t size)
{
    if (!c->ssl) {
        recv_exact(c->fd, data, size);
        return;
    }
    char *p = data;
    while (size > 0) {
        int n = SSL_read(c->ssl, p, (int)size);
        if (n <= 0)
            die("read: TLS read failed");
        p += n;
        size -= (size_t)n;
    }
}

/* One FC04 read of 'count' registers from address 0, its answer checked. */
static void read_input(struct client *c, uint16_t count)
{
    uint8_t req[12], rsp[9 + 250];
    uint16_t tid = ++c->tid;

    req[0] = (uint8_t)(tid >> 8), req[1] = (uint8_t)tid, req[2] = req[3] = 0;
    req[4] = 0, req[5] = 6, req[6] = 1, req[7] = 4;
    req[8] = req[9] = 0, req[10] = (uint8_t)(count >> 8), req[11] = (uint8_t)count;
    io_write(c, req, sizeof(req));
    io_read(c, rsp, 9 + 2u * count);
    if (rsp[0] != req[0] || rsp[1] != req[1] || rsp[7] != 4 || rsp[8] != 2 * count)
        die("unexpected answer to FC04 x %u (function 0x%02x)", count, rsp[7]);
}

static void client_open(struct setup *s, struct client *c, bool tls)
{
    memset(c, 0, sizeof(*c));
    c->fd = connect_loopback(tls ? s->tls_port : s->modbus_port);
    if (!tls)
        return;
    c->ssl = SSL_new(s->ssl);
    if (!c->ssl || SSL_set_fd(c->ssl, c->fd) != 1)
        ssl_die("SSL_new");
    SSL_set1_host(c->ssl, "127.0.0.1");
    if (SSL_connect(c->ssl) != 1)
        ssl_die("TLS handshake with jakagw");
}

static void client_close(struct client *c)
{
    if (c->ssl) {
        SSL_shutdown(c->ssl);
        SSL_free(c->ssl);
    }
    close(c->fd);
}

/* ---- set-up ---- */

static void make_pki(struct setup *s)
{
    char cmd[3 * PATH_MAX];
    snprintf(s->pki, sizeof(s->pki), "%s/pki", bench_tmp_dir);
    snprintf(cmd, sizeof(cmd), "'%s' '%s' >'%s/pki.log' 2>&1", s->pki_script, s->pki,
             bench_tmp_dir);
    if (system(cmd) != 0)
        die("%s failed", s->pki_script);
}

static void client_context(struct setup *s)
{
    char path[PATH_MAX + 32];

    s->ssl = SSL_CTX_new(TLS_client_method());
    if (!s->ssl)
        ssl_die("SSL_CTX_new");
    snprintf(path, sizeof(path), "%s/ca.crt", s->pki);
    if (SSL_CTX_load_verify_locations(s->ssl, path, NULL) != 1)
        ssl_die(path);
    snprintf(path, sizeof(path), "%s/operator.crt", s->pki);
    if (SSL_CTX_use_certificate_file(s->ssl, path, SSL_FILETYPE_PEM) != 1)
        ssl_die(path);
    snprintf(path, sizeof(path), "%s/operator.key", s->pki);
    if (SSL_CTX_use_PrivateKey_file(s->ssl, path, SSL_FILETYPE_PEM) != 1)
        ssl_die(path);
    SSL_CTX_set_verify(s->ssl, SSL_VERIFY_PEER, NULL);
    /* Every handshake a full one: no session is kept to resume. */
    SSL_CTX_set_session_cache_mode(s->ssl, SSL_SESS_CACHE_OFF);
    SSL_CTX_set_options(s->ssl, SSL_OP_NO_TICKET);
}

static void start(struct setup *s)
{
    uint16_t status_port = free_port(), command_port = free_port();
    char sp[8], cp[8];

    s->modbus_port = free_port();
    s->tls_port = free_port();
    snprintf(sp, sizeof(sp), "%u", status_port);
    snprintf(cp, sizeof(cp), "%u", command_port);
    char *sim_argv[] = {(char *)s->jakasim, "--status-port", sp, "--command-port", cp,
                        "--period-ms", "8", NULL};
    pid_t sim = spawn("jakasim", sim_argv, -1);
    wait_listening(status_port, sim, "jakasim");

    char tls[4 * sizeof(s->pki) + 256];
    snprintf(tls, sizeof(tls),
             "[tls]\nenabled = true\nbind = 127.0.0.1\nport = %u\n"
             "certificate = %s/gateway.crt\nprivate_key = %s/gateway.key\n"
             "client_ca = %s/ca.crt\nmax_handshakes = 64\n",
             s->tls_port, s->pki, s->pki, s->pki);
    write_jakagw_config(s->conf, sizeof(s->conf), 2 * MEMORY_CLIENTS + 8, tls);
    s->gw = spawn_jakagw("jakagw", s->jakagw, s->conf, status_port, command_port,
                         s->modbus_port, -1);
    wait_listening(s->tls_port, s->gw, "jakagw (mbaps)");
}

/* ---- measures ---- */

struct window {
    double per_s;       /* requests per second */
    double cpu_per_req; /* server CPU per request, stream cost taken off, µs */
};

/* The server's CPU per second with no client: the status stream. */
static double idle_cpu_rate(struct setup *s)
{
    double cpu = cpu_seconds(s->gw), t = now_s();
    sleep_s(IDLE_WINDOW_S);
    return (cpu_seconds(s->gw) - cpu) / (now_s() - t);
}

static struct window closed_loop(struct setup *s, bool tls, uint16_t count, double idle_rate)
{
    struct client c;
    unsigned n = 0;

    client_open(s, &c, tls);
    read_input(&c, count); /* the handshake stays out of the window */
    double cpu = cpu_seconds(s->gw), t = now_s(), end = t + WINDOW_S, elapsed;
    do {
        for (int i = 0; i < 64; i++, n++)
            read_input(&c, count);
    } while (now_s() < end);
    elapsed = now_s() - t;
    double used = cpu_seconds(s->gw) - cpu - idle_rate * elapsed;
    client_close(&c);
    return (struct window){.per_s = n / elapsed, .cpu_per_req = (used > 0 ? used : 0) / n * 1e6};
}

static void measure_reads(struct setup *s, unsigned rounds)
{
    static const uint16_t counts[] = {10, 125};
    double tput[2][64], cpu[2][64], plain_rate[2][64], plain_cpu[2][64];

    printf("FC04 reads, one client, closed loop; %u rounds of %.1f s windows, "
           "plain and TLS interleaved (medians):\n",
           rounds, WINDOW_S);
    printf("  %-10s %14s %14s %11s %16s %16s %11s\n", "registers", "plain req/s", "TLS req/s",
           "TLS/plain", "plain CPU us/req", "TLS CPU us/req", "TLS/plain");
    for (unsigned r = 0; r < rounds; r++) {
        double idle = idle_cpu_rate(s);
        for (unsigned k = 0; k < 2; k++) {
            /* The order alternates: neither transport always goes first. */
            bool tls_first = (r + k) % 2;
            struct window a = closed_loop(s, tls_first, counts[k], idle);
            struct window b = closed_loop(s, !tls_first, counts[k], idle);
            struct window plain = tls_first ? b : a, tls = tls_first ? a : b;
            plain_rate[k][r] = plain.per_s;
            plain_cpu[k][r] = plain.cpu_per_req;
            tput[k][r] = tls.per_s / plain.per_s;
            cpu[k][r] = plain.cpu_per_req > 0 ? tls.cpu_per_req / plain.cpu_per_req : 0;
            cpu[k][r + rounds] = tls.cpu_per_req;
            tput[k][r + rounds] = tls.per_s;
        }
    }
    for (unsigned k = 0; k < 2; k++) {
        double cpu_ratio = median(cpu[k], rounds);
        printf("  %-10u %14.0f %14.0f %10.2fx %16.1f %16.1f %10.2fx  %s\n", counts[k],
               median(plain_rate[k], rounds), median(tput[k] + rounds, rounds),
               median(tput[k], rounds), median(plain_cpu[k], rounds),
               median(cpu[k] + rounds, rounds), cpu_ratio,
               cpu_ratio <= 1.3 ? "CPU within 1.3x: met" : "CPU within 1.3x: NOT met");
    }
}

static void measure_handshakes(struct setup *s)
{
    static double hs[HANDSHAKES], first[HANDSHAKES];

    for (unsigned i = 0; i < HANDSHAKES; i++) {
        struct client c;
        double t = now_s();
        client_open(s, &c, true);
        hs[i] = (now_s() - t) * 1e3;
        read_input(&c, 1);
        first[i] = (now_s() - t) * 1e3;
        if (SSL_session_reused(c.ssl))
            die("a session was resumed: the handshakes are not full ones");
        client_close(&c);
    }
    printf("Full TLS handshake (%u, no resumption), ms: client done p50 %.2f p99 %.2f; "
           "to the first answer p50 %.2f p99 %.2f\n",
           HANDSHAKES, percentile(hs, HANDSHAKES, 0.5), percentile(hs, HANDSHAKES, 0.99),
           percentile(first, HANDSHAKES, 0.5), percentile(first, HANDSHAKES, 0.99));
}

/* RSS growth (KiB) with MEMORY_CLIENTS connected, each having read once. */
static long rss_growth(struct setup *s, bool tls, long *rss_with)
{
    static struct client c[MEMORY_CLIENTS];
    long before;

    sleep_s(0.2);
    before = status_kib(s->gw, "VmRSS:");
    for (unsigned i = 0; i < MEMORY_CLIENTS; i++) {
        client_open(s, &c[i], tls);
        read_input(&c[i], 125);
    }
    sleep_s(0.2);
    *rss_with = status_kib(s->gw, "VmRSS:");
    for (unsigned i = 0; i < MEMORY_CLIENTS; i++)
        client_close(&c[i]);
    return *rss_with - before;
}

static void measure_memory(struct setup *s)
{
    long plain_rss, tls_rss;
    /* Plain first: the TLS figure must not take the plain one's pages. */
    long plain = rss_growth(s, false, &plain_rss);
    long tls = rss_growth(s, true, &tls_rss);

    printf("Memory: RSS with %u TLS clients %.1f MiB (%s); per connection: TLS %.1f KiB, "
           "plain %.1f KiB\n",
           MEMORY_CLIENTS, tls_rss / 1024.0,
           tls_rss < 16 * 1024 ? "under 16 MiB: met" : "under 16 MiB: NOT met",
           (double)tls / MEMORY_CLIENTS, (double)plain / MEMORY_CLIENTS);
}

/* ---- main ---- */

int main(int argc, char **argv)
{
    struct setup s = {.pki_script = "tests/tls/make-pki.sh"};
    unsigned rounds = 7;

    bench_name = "bench_tls";
    s.jakagw = sibling(argv[0], "../jakagw");
    s.jakasim = sibling(argv[0], "../jakasim");
    for (int i = 1; i < argc; i++) {
        if (i + 1 < argc && strcmp(argv[i], "--jakagw") == 0)
            s.jakagw = argv[++i];
        else if (i + 1 < argc && strcmp(argv[i], "--jakasim") == 0)
            s.jakasim = argv[++i];
        else if (i + 1 < argc && strcmp(argv[i], "--pki-script") == 0)
            s.pki_script = argv[++i];
        else if (i + 1 < argc && strcmp(argv[i], "--rounds") == 0)
            rounds = (unsigned)strtoul(argv[++i], NULL, 10);
        else {
            fprintf(stderr, "usage: bench_tls [--jakagw PATH] [--jakasim PATH] "
                            "[--pki-script PATH] [--rounds N]\n");
            return 2;
        }
    }
    if (rounds < 1 || rounds > 32)
        rounds = 7;
    bench_begin("bench_tls");

    printf("== Modbus/TCP Security against plain Modbus TCP, one jakagw, jakasim at 125 Hz\n");
    make_pki(&s);
    client_context(&s);
    start(&s);
    measure_reads(&s, rounds);
    measure_handshakes(&s);
    measure_memory(&s);
    bench_end();
    SSL_CTX_free(s.ssl);
    return 0;
}
