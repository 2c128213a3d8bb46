/* SPDX-License-Identifier: MIT */
/*
 * bench_proc.h - what a benchmark needs around the programs it measures:
 * children started and stopped by their pid (their output in a temporary
 * directory kept when the run fails), their CPU time and memory from
 * /proc, loopback sockets with timeouts, whole sends and receives, the
 * robot's JSON objects as they arrive, Modbus TCP requests, medians.
 *
 * Header-only (static inline functions): each benchmark is one program
 * built from one file. A benchmark sets bench_name and bench_tmp_dir first.
 */
#ifndef JAKAGW_BENCH_PROC_H
#define JAKAGW_BENCH_PROC_H

#define _GNU_SOURCE /* sched_setaffinity */
#include <errno.h>
#include <fcntl.h>
#include <ftw.h>
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
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define BENCH_IO_TIMEOUT_S 10

static const char *bench_name = "bench";
static char bench_tmp_dir[PATH_MAX];
static pid_t bench_children[8];
static unsigned bench_child_count;

static inline double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static inline double now_us(void)
{
    return now_s() * 1e6;
}

static inline int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Sorts v. */
static inline double percentile(double *v, unsigned n, double p)
{
    qsort(v, n, sizeof(v[0]), cmp_double);
    return v[(unsigned)(p * (n - 1) + 0.5)];
}

static inline double median(double *v, unsigned n)
{
    return percentile(v, n, 0.5);
}

static inline void sleep_s(double s)
{
    struct timespec ts = {(time_t)s, (long)((s - (double)(time_t)s) * 1e9)};
    while (nanosleep(&ts, &ts) < 0 && errno == EINTR)
        ;
}

static inline void stop_child(pid_t pid)
{
    int status;

    if (pid <= 0)
        return;
    kill(pid, SIGTERM);
    for (int i = 0; i < 1000; i++) {
        if (waitpid(pid, &status, WNOHANG) == pid)
            goto reaped;
        sleep_s(0.01);
    }
    kill(pid, SIGKILL);
    waitpid(pid, &status, 0);
reaped:
    for (unsigned i = 0; i < bench_child_count; i++)
        if (bench_children[i] == pid)
            bench_children[i] = 0;
}

static inline void stop_children(void)
{
    for (unsigned i = 0; i < bench_child_count; i++)
        stop_child(bench_children[i]);
    bench_child_count = 0;
}

/* Stops every child and exits; the temporary directory stays to look at. */
static inline void die(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "%s: ", bench_name);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, " (logs in %s)\n", bench_tmp_dir);
    va_end(ap);
    stop_children();
    exit(1);
}

static inline void pin_to(int cpu)
{
    cpu_set_t set;

    if (cpu < 0)
        return;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (sched_setaffinity(0, sizeof(set), &set) < 0)
        fprintf(stderr, "%s: cannot pin to CPU %d: %s\n", bench_name, cpu, strerror(errno));
}

/* Runs argv with its output in TMP/NAME.log, on 'cpu' (-1: anywhere). */
static inline pid_t spawn(const char *name, char *const argv[], int cpu)
{
    char log[PATH_MAX + 32];
    pid_t pid;

    snprintf(log, sizeof(log), "%s/%s.log", bench_tmp_dir, name);
    pid = fork();
    if (pid < 0)
        die("fork: %s", strerror(errno));
    if (pid == 0) {
        int fd = open(log, O_WRONLY | O_CREAT | O_APPEND, 0600);
        if (fd >= 0) {
            dup2(fd, STDOUT_FILENO);
            dup2(fd, STDERR_FILENO);
            close(fd);
        }
        pin_to(cpu);
        execv(argv[0], argv);
        fprintf(stderr, "cannot run %s: %s\n", argv[0], strerror(errno));
        _exit(127);
    }
    if (bench_child_count < sizeof(bench_children) / sizeof(bench_children[0]))
        bench_children[bench_child_count++] = pid;
    return pid;
}

static inline bool child_alive(pid_t pid)
{
    int status;
    return waitpid(pid, &status, WNOHANG) == 0;
}

/* utime + stime, in seconds, from /proc/PID/stat. */
static inline double cpu_seconds(pid_t pid)
{
    char path[64], buf[1024];
    unsigned long utime, stime;

    snprintf(path, sizeof(path), "/proc/%d/stat", (int)pid);
    FILE *f = fopen(path, "r");
    if (!f)
        die("%s: %s", path, strerror(errno));
    size_t n = fread(buf, 1, sizeof(buf) - 1, f);
    fclose(f);
    buf[n] = '\0';
    /* The name may hold spaces and parentheses: fields follow the last ')'. */
    char *p = strrchr(buf, ')');
    if (!p ||
        sscanf(p + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %lu %lu", &utime, &stime) != 2)
        die("%s: unexpected format", path);
    return (double)(utime + stime) / (double)sysconf(_SC_CLK_TCK);
}

/* A "VmRSS:"-style line of /proc/PID/status, in KiB. */
static inline long status_kib(pid_t pid, const char *key)
{
    char path[64], line[256];
    long kib = -1;
    size_t len = strlen(key);

    snprintf(path, sizeof(path), "/proc/%d/status", (int)pid);
    FILE *f = fopen(path, "r");
    if (!f)
        die("%s: %s", path, strerror(errno));
    while (fgets(line, sizeof(line), f))
        if (strncmp(line, key, len) == 0)
            kib = strtol(line + len, NULL, 10);
    fclose(f);
    return kib;
}

/* A loopback listener on a port the kernel picks. */
static inline int listen_loopback(uint16_t *port)
{
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof(sa);
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);

    if (fd < 0 || bind(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0 || listen(fd, 8) < 0 ||
        getsockname(fd, (struct sockaddr *)&sa, &len) < 0)
        die("listen: %s", strerror(errno));
    *port = ntohs(sa.sin_port);
    return fd;
}

/* A port nobody listens on now (the child binds it a moment later). */
static inline uint16_t free_port(void)
{
    uint16_t port;
    close(listen_loopback(&port));
    return port;
}

/* I/O timeouts and TCP_NODELAY: a stuck peer fails the run, not hangs it. */
static inline void set_timeouts(int fd)
{
    struct timeval tv = {BENCH_IO_TIMEOUT_S, 0};
    int one = 1;
    if (setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv)) < 0 ||
        setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof(tv)) < 0 ||
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one)) < 0)
        die("setsockopt: %s", strerror(errno));
}

/* A loopback connection with set_timeouts; -1 if refused. */
static inline int try_connect(uint16_t port)
{
    struct sockaddr_in sa = {
        .sin_family = AF_INET, .sin_port = htons(port), .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);

    if (fd < 0)
        die("socket: %s", strerror(errno));
    if (connect(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0) {
        close(fd);
        return -1;
    }
    set_timeouts(fd);
    return fd;
}

static inline int connect_loopback(uint16_t port)
{
    int fd = try_connect(port);
    if (fd < 0)
        die("connect to port %u: %s", port, strerror(errno));
    return fd;
}

/* The next connection on 'listener' within 'seconds', with set_timeouts. */
static inline int accept_within(int listener, double seconds, const char *what)
{
    struct pollfd p = {.fd = listener, .events = POLLIN};
    if (poll(&p, 1, (int)(seconds * 1000)) != 1)
        die("%s did not connect", what);
    int fd = accept4(listener, NULL, NULL, SOCK_CLOEXEC);
    if (fd < 0)
        die("accept: %s", strerror(errno));
    set_timeouts(fd);
    return fd;
}

/* All of 'size' bytes, or the run fails. */
static inline void send_all(int fd, const void *data, size_t size)
{
    const char *p = data;
    while (size > 0) {
        ssize_t n = send(fd, p, size, MSG_NOSIGNAL);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            die("send: %s", n < 0 ? strerror(errno) : "nothing sent");
        p += n;
        size -= (size_t)n;
    }
}

/* Exactly 'size' bytes, or the run fails (a peer that closed, a timeout). */
static inline void recv_exact(int fd, void *data, size_t size)
{
    char *p = data;
    while (size > 0) {
        ssize_t n = recv(fd, p, size, 0);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            die("recv: %s", n < 0 ? strerror(errno) : "connection closed");
        p += n;
        size -= (size_t)n;
    }
}

/* One JSON object as the gateway writes it to the robot: whole reads (it
 * writes one object and waits for the answer), braces counted outside
 * strings. */
struct object_reader {
    char buf[4096];
    size_t size;
};

/* Reads one object into r->buf (NUL-terminated); returns now_us() when
 * its last byte arrived, or -1 when nothing came for 'timeout_ms' (-1:
 * wait as long as the socket's timeout allows). */
static inline double read_object(int fd, struct object_reader *r, int timeout_ms)
{
    int depth = 0;
    bool in_string = false, escaped = false, started = false;

    r->size = 0;
    for (;;) {
        if (timeout_ms >= 0) {
            struct pollfd p = {.fd = fd, .events = POLLIN};
            if (poll(&p, 1, timeout_ms) != 1)
                return -1;
        }
        ssize_t n = recv(fd, r->buf + r->size, sizeof(r->buf) - 1 - r->size, 0);
        double t = now_us();
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            die("recv (robot side): %s", n < 0 ? strerror(errno) : "connection closed");
        for (size_t i = r->size; i < r->size + (size_t)n; i++) {
            char c = r->buf[i];
            if (in_string) {
                if (escaped)
                    escaped = false;
                else if (c == '\\')
                    escaped = true;
                else if (c == '"')
                    in_string = false;
            } else if (c == '"') {
                in_string = true;
            } else if (c == '{') {
                depth++;
                started = true;
            } else if (c == '}') {
                depth--;
            }
        }
        r->size += (size_t)n;
        r->buf[r->size] = '\0';
        if (started && depth == 0)
            return t;
        if (r->size >= sizeof(r->buf) - 1)
            die("an object of more than %zu bytes from the gateway", sizeof(r->buf) - 1);
    }
}

/*
 * A Modbus TCP request for unit 1 of the form every function here has:
 * function, address, and a value (FC05, FC06) or a count (FC03, FC04).
 */
static inline void modbus_tcp_send(int fd, uint16_t tid, uint8_t function, uint16_t address,
                                   uint16_t value)
{
    uint8_t req[12] = {(uint8_t)(tid >> 8), (uint8_t)tid, 0, 0, 0, 6, 1, function,
                       (uint8_t)(address >> 8), (uint8_t)address, (uint8_t)(value >> 8),
                       (uint8_t)value};
    send_all(fd, req, sizeof(req));
}

/* Its answer, 'size' bytes with the MBAP header; an exception fails the run. */
static inline void modbus_tcp_answer(int fd, uint8_t function, uint8_t *rsp, size_t size,
                                     const char *server)
{
    recv_exact(fd, rsp, 9);
    if (rsp[7] != function)
        die("%s answered function %u with exception %u", server, function, rsp[8]);
    recv_exact(fd, rsp + 9, size - 9);
}

static inline void wait_listening(uint16_t port, pid_t pid, const char *name)
{
    double deadline = now_s() + 30;
    while (now_s() < deadline) {
        int fd = try_connect(port);
        if (fd >= 0) {
            close(fd);
            return;
        }
        if (!child_alive(pid))
            die("%s exited at start", name);
        sleep_s(0.02);
    }
    die("%s does not listen on port %u after 30 s", name, port);
}

/*
 * Writes TMP/jakagw.conf into 'path': the settings every benchmark's
 * jakagw shares (room for 'max_clients', no idle closing, a status link
 * that never times out, quiet logs), then 'extra' (more sections, or "").
 */
static inline void write_jakagw_config(char *path, size_t size, unsigned max_clients,
                                       const char *extra)
{
    snprintf(path, size, "%s/jakagw.conf", bench_tmp_dir);
    FILE *f = fopen(path, "w");
    if (!f)
        die("%s: %s", path, strerror(errno));
    fprintf(f,
            "[modbus]\nmax_clients = %u\nidle_timeout_ms = 0\n"
            "[robot]\nstatus_timeout_ms = 600000\n"
            "[log]\nlevel = warning\n%s",
            max_clients, extra);
    fclose(f);
}

/*
 * Starts jakagw with configuration 'conf', robot ports 'status_port' and
 * 'command_port' on 127.0.0.1, Modbus on 127.0.0.1:'modbus_port', on 'cpu';
 * returns once it listens.
 */
static inline pid_t spawn_jakagw(const char *name, const char *jakagw, const char *conf,
                                 uint16_t status_port, uint16_t command_port,
                                 uint16_t modbus_port, int cpu)
{
    char sp[8], cp[8], mp[8];
    snprintf(sp, sizeof(sp), "%u", status_port);
    snprintf(cp, sizeof(cp), "%u", command_port);
    snprintf(mp, sizeof(mp), "%u", modbus_port);
    char *argv[] = {(char *)jakagw, "-c", (char *)conf, "--robot-host", "127.0.0.1",
                    "--status-port", sp, "--command-port", cp, "--modbus-bind", "127.0.0.1",
                    "--modbus-port", mp, NULL};
    pid_t pid = spawn(name, argv, cpu);
    wait_listening(modbus_port, pid, name);
    return pid;
}

/* A file next to the benchmark (argv0's directory), as a path. */
static inline const char *sibling(const char *argv0, const char *rel)
{
    static char buf[4][2 * PATH_MAX];
    static unsigned used;
    char dir[PATH_MAX];

    snprintf(dir, sizeof(dir), "%s", argv0);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = '\0';
    else
        snprintf(dir, sizeof(dir), ".");
    char *b = buf[used++ % 4];
    snprintf(b, sizeof(buf[0]), "%s/%s", dir, rel);
    return b;
}

static inline int remove_entry(const char *path, const struct stat *st, int flag,
                               struct FTW *ftw)
{
    (void)st, (void)flag, (void)ftw;
    return remove(path);
}

/* Stops every child and removes the benchmark's directory: a run that
 * ended well leaves nothing behind (die() keeps it, to look at). */
static inline void bench_end(void)
{
    stop_children();
    if (bench_tmp_dir[0] && nftw(bench_tmp_dir, remove_entry, 8, FTW_DEPTH | FTW_PHYS) != 0)
        fprintf(stderr, "%s: could not remove %s: %s\n", bench_name, bench_tmp_dir,
                strerror(errno));
}

/* SIGINT, SIGTERM: no child outlives the benchmark. */
static inline void on_fatal_signal(int sig)
{
    (void)sig;
    stop_children();
    _exit(1);
}

/* Makes the benchmark's directory for logs and files (/tmp/NAME.XXXXXX)
 * and sees that SIGINT and SIGTERM stop its children; SIGPIPE ignored. */
static inline void bench_begin(const char *name)
{
    bench_name = name;
    signal(SIGPIPE, SIG_IGN);
    signal(SIGINT, on_fatal_signal);
    signal(SIGTERM, on_fatal_signal);
    snprintf(bench_tmp_dir, sizeof(bench_tmp_dir), "/tmp/%s.XXXXXX", name);
    if (!mkdtemp(bench_tmp_dir))
        die("mkdtemp: %s", strerror(errno));
}

#endif
