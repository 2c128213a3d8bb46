/* SPDX-License-Identifier: MIT */
/*
 * bench_rtu.c - Modbus RTU on a serial line, measured over socat pty pairs
 * at 115200 baud 8N1 (a pty does not pace bytes at the baud rate: what is
 * measured is the software, plus the silences each side keeps):
 *
 *   - FC04 reads of 10 registers by a libmodbus RTU master in a closed
 *     loop: requests per second and the server's CPU per request, jakagw
 *     (jakasim streaming at 125 Hz, whose cost alone is measured first and
 *     taken off) against a bare libmodbus RTU slave (modbus_receive and
 *     modbus_reply on the same kind of pty, no foreign units: the case
 *     where libmodbus keeps its sync), and the turnaround jakagw reports;
 *     then both at the same load (PACE_HZ requests a second), for CPU per
 *     request at a PLC's poll rate;
 *   - FC04 reads of 10 registers over Modbus TCP, one client in a closed
 *     loop, alone and while the RTU master polls at the same time;
 *   - a multi-drop bus: a request for another unit, 5 ms of silence, a
 *     request for ours, 50 times: how many of ours each slave answers
 *     (libmodbus 3.1.6 waits for the other unit's reply and loses sync).
 *
 *   bench_rtu [--jakagw PATH] [--jakasim PATH] [--rounds N]
 */
#include "bench_proc.h"

#include <modbus.h>
#include <poll.h>
#include <sys/stat.h>
#include <termios.h>

#define WINDOW_S 2.0
#define IDLE_WINDOW_S 2.0
#define BAUD 115200
#define UNIT 1
#define IR_TURNAROUND 5554
/* A PLC's poll rate both slaves can keep: CPU per request compared at the
 * same load (a slave answering back to back runs with warm caches). */
#define PACE_HZ 200

struct setup {
    const char *jakagw, *jakasim;
    char conf[PATH_MAX + 64];
    pid_t gw, ref;
    uint16_t modbus_port;
    char gw_master[PATH_MAX + 64], ref_master[PATH_MAX + 64];
};

struct window {
    double per_s;       /* requests per second */
    double cpu_per_req; /* server CPU per request, idle cost taken off, us */
};

/* CPU time of 'pid''s main thread (the event loop), ns resolution, from
 * /proc/PID/schedstat: a paced window uses a few ms, less than the
 * 10 ms tick of /proc/PID/stat. */
static double loop_cpu_seconds(pid_t pid)
{
    char path[64];
    unsigned long long ns = 0;
    snprintf(path, sizeof(path), "/proc/%d/schedstat", (int)pid);
    FILE *f = fopen(path, "r");
    if (!f || fscanf(f, "%llu", &ns) != 1)
        die("%s: cannot read", path);
    fclose(f);
    return (double)ns / 1e9;
}

static bool exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

/* socat joining two ptys, linked as DIR/NAME-dev and DIR/NAME-master. */
static void serial_pair(const char *name, char *device, char *master)
{
    char a[PATH_MAX + 128], b[PATH_MAX + 128];

    snprintf(device, PATH_MAX + 64, "%s/%s-dev", bench_tmp_dir, name);
    snprintf(master, PATH_MAX + 64, "%s/%s-master", bench_tmp_dir, name);
    snprintf(a, sizeof(a), "pty,raw,echo=0,link=%s", device);
    snprintf(b, sizeof(b), "pty,raw,echo=0,ignoreeof,link=%s", master);
    char *argv[] = {"/usr/bin/socat", a, b, NULL};
    pid_t pid = spawn(name, argv, -1);
    for (int i = 0; i < 1500 && !(exists(device) && exists(master)); i++) {
        if (!child_alive(pid))
            die("socat exited (is it installed?)");
        sleep_s(0.02);
    }
    if (!(exists(device) && exists(master)))
        die("socat made no ptys in 30 s");
}

/* The reference: libmodbus alone, as a serial slave is usually written. */
static void ref_slave_loop(const char *device)
{
    modbus_t *ctx = modbus_new_rtu(device, BAUD, 'N', 8, 1);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 0, 10000);
    uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH];

    if (!ctx || !map || modbus_set_slave(ctx, UNIT) < 0 || modbus_connect(ctx) < 0)
        _exit(3);
    for (;;) {
        int n = modbus_receive(ctx, query);
        if (n > 0)
            modbus_reply(ctx, query, n, map);
    }
}

static pid_t spawn_ref_slave(const char *device)
{
    pid_t pid = fork();
    if (pid < 0)
        die("fork: %s", strerror(errno));
    if (pid == 0) {
        signal(SIGTERM, SIG_DFL);
        signal(SIGINT, SIG_DFL);
        ref_slave_loop(device);
    }
    bench_children[bench_child_count++] = pid;
    return pid;
}

static modbus_t *rtu_master(const char *path)
{
    modbus_t *ctx = modbus_new_rtu(path, BAUD, 'N', 8, 1);
    if (!ctx || modbus_set_slave(ctx, UNIT) < 0 || modbus_connect(ctx) < 0)
        die("RTU master on %s: %s", path, modbus_strerror(errno));
    modbus_set_response_timeout(ctx, 1, 0);
    /* A master stopped mid-request left its reply on the line: taken for
     * the answer to our first request, it would pipeline every later one. */
    sleep_s(0.02);
    modbus_flush(ctx);
    return ctx;
}

/* t3.5 at 115200 baud and the request's own wire time, and a little: when
 * a master's next request arrives after a reply on a wire. libmodbus's master does not wait it, and a pty
 * delivers the reply at once (a wire would take its 25 bytes' time):
 * jakagw never executes a frame that comes before its reply's end plus
 * t3.5 (it could be that reply heard back), so the master here keeps the
 * silence the specification asks for, against both slaves alike. */
#define MASTER_SILENCE_S 0.003 /* t3.5, the request's 8 characters, a margin */

static void read_rtu(modbus_t *ctx)
{
    uint16_t regs[10];
    if (modbus_read_input_registers(ctx, 0, 10, regs) != 10)
        die("RTU read: %s", modbus_strerror(errno));
    sleep_s(MASTER_SILENCE_S);
}

static void start(struct setup *s)
{
    uint16_t status_port = free_port(), command_port = free_port();
    char sp[8], cp[8], device[PATH_MAX + 64], ref_device[PATH_MAX + 64], extra[PATH_MAX + 256];

    serial_pair("gwline", device, s->gw_master);
    serial_pair("refline", ref_device, s->ref_master);
    s->modbus_port = free_port();
    snprintf(sp, sizeof(sp), "%u", status_port);
    snprintf(cp, sizeof(cp), "%u", command_port);
    char *sim_argv[] = {(char *)s->jakasim, "--status-port", sp, "--command-port", cp,
                        "--period-ms", "8", NULL};
    pid_t sim = spawn("jakasim", sim_argv, -1);
    wait_listening(status_port, sim, "jakasim");
    snprintf(extra, sizeof(extra),
             "[rtu]\nenabled = true\ndevice = %s\nbaud = %u\nparity = none\nunit_id = %u\n",
             device, BAUD, UNIT);
    write_jakagw_config(s->conf, sizeof(s->conf), 8, extra);
    s->gw = spawn_jakagw("jakagw", s->jakagw, s->conf, status_port, command_port,
                         s->modbus_port, -1);
    s->ref = spawn_ref_slave(ref_device);
}

static double idle_cpu_rate(pid_t pid, double (*cpu_of)(pid_t))
{
    double cpu = cpu_of(pid), t = now_s();
    sleep_s(IDLE_WINDOW_S);
    return (cpu_of(pid) - cpu) / (now_s() - t);
}

/* A window of reads: back to back (pace_hz 0), or 'pace_hz' a second. */
static struct window rtu_window(const char *master, pid_t server, double idle_rate,
                                double pace_hz)
{
    modbus_t *ctx = rtu_master(master);
    unsigned n = 0;

    read_rtu(ctx);
    double cpu = loop_cpu_seconds(server), t = now_s(), end = t + WINDOW_S, elapsed;
    do {
        if (pace_hz > 0) {
            double due = t + n / pace_hz;
            if (now_s() < due)
                sleep_s(due - now_s());
            read_rtu(ctx);
            n++;
            continue;
        }
        for (int i = 0; i < 16; i++, n++)
            read_rtu(ctx);
    } while (now_s() < end);
    elapsed = now_s() - t;
    double used = loop_cpu_seconds(server) - cpu - idle_rate * elapsed;
    modbus_close(ctx);
    modbus_free(ctx);
    return (struct window){.per_s = n / elapsed,
                           .cpu_per_req = (used > 0 ? used : 0) / n * 1e6};
}

static modbus_t *tcp_client(struct setup *s)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", s->modbus_port);
    if (!ctx || modbus_connect(ctx) < 0)
        die("Modbus TCP connect: %s", modbus_strerror(errno));
    modbus_set_slave(ctx, UNIT);
    return ctx;
}

static struct window tcp_window(struct setup *s, double idle_rate)
{
    modbus_t *ctx = tcp_client(s);
    uint16_t regs[10];
    unsigned n = 0;

    double cpu = cpu_seconds(s->gw), t = now_s(), end = t + WINDOW_S, elapsed;
    do {
        for (int i = 0; i < 64; i++, n++)
            if (modbus_read_input_registers(ctx, 0, 10, regs) != 10)
                die("TCP read: %s", modbus_strerror(errno));
    } while (now_s() < end);
    elapsed = now_s() - t;
    double used = cpu_seconds(s->gw) - cpu - idle_rate * elapsed;
    modbus_close(ctx);
    modbus_free(ctx);
    return (struct window){.per_s = n / elapsed,
                           .cpu_per_req = (used > 0 ? used : 0) / n * 1e6};
}

/* An RTU master polling jakagw as fast as it answers, in a child. */
static pid_t start_rtu_poller(struct setup *s)
{
    pid_t pid = fork();
    if (pid < 0)
        die("fork: %s", strerror(errno));
    if (pid == 0) {
        signal(SIGTERM, SIG_DFL);
        modbus_t *ctx = rtu_master(s->gw_master);
        for (;;)
            read_rtu(ctx);
    }
    bench_children[bench_child_count++] = pid;
    sleep_s(0.2);
    return pid;
}

static void stop_poller(pid_t pid)
{
    kill(pid, SIGTERM);
    waitpid(pid, NULL, 0);
    for (unsigned i = 0; i < bench_child_count; i++)
        if (bench_children[i] == pid)
            bench_children[i] = bench_children[--bench_child_count];
}

static uint32_t read_u32(struct setup *s, int address)
{
    modbus_t *ctx = tcp_client(s);
    uint16_t regs[2];
    if (modbus_read_input_registers(ctx, address, 2, regs) != 2)
        die("TCP read of %d: %s", address, modbus_strerror(errno));
    modbus_close(ctx);
    modbus_free(ctx);
    return (uint32_t)regs[0] << 16 | regs[1];
}

static uint16_t crc16(const uint8_t *p, size_t n)
{
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < n; i++) {
        crc ^= p[i];
        for (int b = 0; b < 8; b++)
            crc = crc & 1 ? (uint16_t)((crc >> 1) ^ 0xA001) : (uint16_t)(crc >> 1);
    }
    return crc;
}

static void send_read(int fd, uint8_t unit)
{
    uint8_t f[8] = {unit, 4, 0, 0, 0, 10};
    uint16_t crc = crc16(f, 6);
    f[6] = (uint8_t)crc, f[7] = (uint8_t)(crc >> 8);
    if (write(fd, f, sizeof(f)) != (ssize_t)sizeof(f))
        die("write to the master pty: %s", strerror(errno));
}

/* Ours answered: 25 bytes of FC04 x10 for UNIT within 200 ms. */
static bool answered(int fd)
{
    uint8_t buf[64];
    size_t got = 0;
    double end = now_s() + 0.2;

    while (got < 25 && now_s() < end) {
        struct pollfd p = {.fd = fd, .events = POLLIN};
        if (poll(&p, 1, 20) <= 0)
            continue;
        ssize_t n = read(fd, buf + got, sizeof(buf) - got);
        if (n > 0)
            got += (size_t)n;
    }
    return got == 25 && buf[0] == UNIT && buf[1] == 4 && crc16(buf, 23) == (buf[23] | buf[24] << 8);
}

static unsigned multidrop(const char *master)
{
    int fd = open(master, O_RDWR | O_NOCTTY);
    struct termios tio;
    unsigned ok = 0;

    if (fd < 0 || tcgetattr(fd, &tio) < 0)
        die("%s: %s", master, strerror(errno));
    cfmakeraw(&tio);
    tcsetattr(fd, TCSANOW, &tio);
    sleep_s(0.1); /* a reply to a master stopped mid-request lands, and goes */
    tcflush(fd, TCIOFLUSH);
    for (int i = 0; i < 50; i++) {
        send_read(fd, UNIT + 1);
        sleep_s(0.005);
        send_read(fd, UNIT);
        ok += answered(fd);
        sleep_s(0.005);
    }
    close(fd);
    return ok;
}

/* Each reply's turnaround as jakagw measures it (the request's last byte
 * read to the reply written, t3.5 included), read over TCP after every
 * one of 'n' requests: the median and the 90th percentile, in us. */
static void turnaround_samples(struct setup *s, unsigned n, double *median_us, double *p90_us)
{
    static double t[1000];
    modbus_t *ctx = rtu_master(s->gw_master);
    if (n > 1000)
        n = 1000;
    for (unsigned i = 0; i < n; i++) {
        read_rtu(ctx);
        t[i] = read_u32(s, IR_TURNAROUND);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    qsort(t, n, sizeof(t[0]), cmp_double);
    *median_us = t[n / 2];
    *p90_us = t[n * 9 / 10];
}

static void measure(struct setup *s, unsigned rounds)
{
    double gw_rate[32], gw_cpu[32], ref_rate[32], ref_cpu[32], turnaround[32];
    double tcp_rate[32], tcp_cpu[32], both_rate[32], both_cpu[32], rtu_rate_with[32];
    double gw_idle = idle_cpu_rate(s->gw, loop_cpu_seconds),
           ref_idle = idle_cpu_rate(s->ref, loop_cpu_seconds),
           gw_idle_all = idle_cpu_rate(s->gw, cpu_seconds);

    double gw_paced[32], ref_paced[32];
    for (unsigned r = 0; r < rounds; r++) {
        struct window g = rtu_window(s->gw_master, s->gw, gw_idle, 0);
        turnaround[r] = read_u32(s, IR_TURNAROUND);
        struct window f = rtu_window(s->ref_master, s->ref, ref_idle, 0);
        gw_rate[r] = g.per_s, gw_cpu[r] = g.cpu_per_req;
        ref_rate[r] = f.per_s, ref_cpu[r] = f.cpu_per_req;
        gw_paced[r] = rtu_window(s->gw_master, s->gw, gw_idle, PACE_HZ).cpu_per_req;
        ref_paced[r] = rtu_window(s->ref_master, s->ref, ref_idle, PACE_HZ).cpu_per_req;
    }
    printf("RTU FC04 x10 at %u baud 8N1 over a pty, one master, closed loop; %u rounds of "
           "%.1f s, medians\n", BAUD, rounds, WINDOW_S);
    printf("  %-24s %12s %16s\n", "", "req/s", "loop CPU/req");
    printf("  %-24s %12.0f %13.1f us\n", "jakagw", median(gw_rate, rounds),
           median(gw_cpu, rounds));
    printf("  %-24s %12.0f %13.1f us\n", "libmodbus RTU slave", median(ref_rate, rounds),
           median(ref_cpu, rounds));
    printf("  %-24s %11.2fx %15.2fx\n", "jakagw / libmodbus",
           median(gw_rate, rounds) / median(ref_rate, rounds),
           median(gw_cpu, rounds) / median(ref_cpu, rounds));
    printf("  at the same load, %d req/s from both: loop CPU/req jakagw %.1f us, "
           "libmodbus %.1f us: %.2fx\n",
           PACE_HZ, median(gw_paced, rounds), median(ref_paced, rounds),
           median(gw_paced, rounds) / median(ref_paced, rounds));
    printf("  jakagw turnaround (request's last byte read to reply written, t3.5 = 1750 us "
           "included): %.0f us median of the rounds' last, %u us max\n",
           median(turnaround, rounds), read_u32(s, IR_TURNAROUND + 2));
    double t_median, t_p90;
    turnaround_samples(s, 400, &t_median, &t_p90);
    printf("  jakagw turnaround over 400 requests: median %.0f us, 90th percentile %.0f us "
           "(t3.5 + 200 us = 1950 us)\n", t_median, t_p90);

    for (unsigned r = 0; r < rounds; r++) {
        struct window alone = tcp_window(s, gw_idle_all);
        pid_t poller = start_rtu_poller(s);
        double frames = read_u32(s, 5542), t = now_s();
        struct window both = tcp_window(s, gw_idle_all);
        rtu_rate_with[r] = (read_u32(s, 5542) - frames) / (now_s() - t);
        stop_poller(poller);
        tcp_rate[r] = alone.per_s, tcp_cpu[r] = alone.cpu_per_req;
        both_rate[r] = both.per_s, both_cpu[r] = both.cpu_per_req;
    }
    printf("Modbus TCP FC04 x10, one client, closed loop, alone and with the RTU master "
           "polling; medians\n");
    printf("  TCP alone      %8.0f req/s\n", median(tcp_rate, rounds));
    printf("  TCP + RTU      %8.0f req/s (RTU %0.f frames/s at the same time): %.2fx\n",
           median(both_rate, rounds), median(rtu_rate_with, rounds),
           median(both_rate, rounds) / median(tcp_rate, rounds));
    printf("  server CPU per request: %.1f us alone, %.1f us with RTU (both kinds counted)\n",
           median(tcp_cpu, rounds), median(both_cpu, rounds));
    unsigned gw_ok = multidrop(s->gw_master), ref_ok = multidrop(s->ref_master);
    printf("Multi-drop: 50 requests for unit %u, each after one for unit %u: jakagw answered "
           "%u, libmodbus %u\n", UNIT, UNIT + 1, gw_ok, ref_ok);
}

int main(int argc, char **argv)
{
    struct setup s;
    unsigned rounds = 3;

    memset(&s, 0, sizeof(s));
    bench_name = "bench_rtu";
    s.jakagw = sibling(argv[0], "../jakagw");
    s.jakasim = sibling(argv[0], "../jakasim");
    for (int i = 1; i < argc; i++) {
        if (i + 1 < argc && strcmp(argv[i], "--jakagw") == 0)
            s.jakagw = argv[++i];
        else if (i + 1 < argc && strcmp(argv[i], "--jakasim") == 0)
            s.jakasim = argv[++i];
        else if (i + 1 < argc && strcmp(argv[i], "--rounds") == 0)
            rounds = (unsigned)strtoul(argv[++i], NULL, 10);
        else {
            fprintf(stderr, "usage: bench_rtu [--jakagw PATH] [--jakasim PATH] [--rounds N]\n");
            return 2;
        }
    }
    if (rounds < 1 || rounds > 32)
        rounds = 3;
    bench_begin("bench_rtu");

    printf("== Modbus RTU: jakagw against a bare libmodbus RTU slave, socat ptys\n");
    start(&s);
    measure(&s, rounds);
    bench_end();
    return 0;
}
