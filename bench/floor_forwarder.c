/* SPDX-License-Identifier: MIT */
/*
 * floor_forwarder.c - the least a Modbus-to-robot forwarder can do, as the
 * floor that bench_forward measures jakagw against.
 *
 * One epoll loop, no library: it connects to the robot's status and
 * command ports and serves one Modbus TCP client. An FC05 that writes ON
 * sends a fixed command ({"cmdName":"power_on"}) to the command port and
 * echoes the request (the reply FC05 has, Modbus Application Protocol
 * 1.1b3, 6.5); an FC05 that writes OFF is echoed only; an FC04 of one
 * register answers the "len" of the newest status document. The status
 * stream is framed by its "len" headers (manual 2.0.4, the status port
 * writes '{"len": N, ...}' documents back to back) and only the field is
 * read; the robot's replies are read and dropped. Nothing is checked that
 * a real gateway must check: it is a floor, not a gateway.
 *
 *   floor_forwarder STATUS_PORT COMMAND_PORT MODBUS_PORT
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <unistd.h>

#define STATUS_BUF (256 * 1024)

static const char command[] = "{\"cmdName\":\"power_on\"}";

static int connect_port(unsigned port)
{
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    int one = 1;
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0 || connect(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0) {
        perror("floor_forwarder: connect");
        exit(1);
    }
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    return fd;
}

static int listen_port(unsigned port)
{
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    int one = 1;
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    if (fd < 0 || bind(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0 || listen(fd, 4) < 0) {
        perror("floor_forwarder: listen");
        exit(1);
    }
    return fd;
}

static void watch(int ep, int fd)
{
    struct epoll_event ev = {.events = EPOLLIN, .data.fd = fd};
    if (epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev) < 0) {
        perror("floor_forwarder: epoll_ctl");
        exit(1);
    }
}

/* The status stream: documents framed by their "len"; the newest's "len" kept. */
struct status_reader {
    char buf[STATUS_BUF];
    size_t used;
    unsigned value;
};

static void take_status(struct status_reader *s, int fd)
{
    ssize_t n = read(fd, s->buf + s->used, sizeof(s->buf) - s->used);
    if (n <= 0)
        exit(n == 0 ? 0 : 1);
    s->used += (size_t)n;
    for (;;) {
        const char *len = memmem(s->buf, s->used < 64 ? s->used : 64, "\"len\"", 5);
        if (!len)
            break;
        unsigned size = (unsigned)strtoul(strchr(len, ':') + 1, NULL, 10);
        if (size == 0 || size > sizeof(s->buf)) {
            s->used = 0; /* lost: a floor does not resynchronise */
            break;
        }
        if (s->used < size)
            break;
        s->value = size;
        memmove(s->buf, s->buf + size, s->used - size);
        s->used -= size;
    }
    if (s->used == sizeof(s->buf))
        s->used = 0;
}

/* The functions bench_forward's callgrind counts from (--toggle-collect
 * takes a symbol's name): never inlined, and never cloned either. GCC
 * propagates serve()'s constant argument into a clone named
 * "serve.constprop.0", which --toggle-collect=serve does not match, and
 * only drop_reply() was counted: 16 instructions per command. */
#if defined(__clang__)
#define COUNTED __attribute__((noinline))
#else
#define COUNTED __attribute__((noinline, noclone))
#endif

static void write_all(int fd, const void *data, size_t size)
{
    if (write(fd, data, size) != (ssize_t)size) {
        perror("floor_forwarder: write");
        exit(1);
    }
}

/* The robot's replies: read and dropped. Callgrind counts from here
 * (bench_forward). */
COUNTED static void drop_reply(int robot)
{
    char drop[4096];
    if (read(robot, drop, sizeof(drop)) <= 0)
        exit(0);
}

/* One request per read: the bench's client sends one and waits.
 * Callgrind counts from here. */
COUNTED static void serve(int client, int robot, const struct status_reader *s)
{
    uint8_t req[260];
    ssize_t n = read(client, req, sizeof(req));
    if (n <= 0) {
        close(client); /* leaves the epoll set with it */
        return;
    }
    if (n < 12)
        return;
    if (req[7] == 5) {
        if (req[10] == 0xFF)
            write_all(robot, command, sizeof(command) - 1);
        write_all(client, req, 12);
    } else if (req[7] == 4) {
        uint8_t rsp[11];
        memcpy(rsp, req, 7);
        rsp[4] = 0;
        rsp[5] = 5;
        rsp[7] = 4;
        rsp[8] = 2;
        rsp[9] = (uint8_t)(s->value >> 8);
        rsp[10] = (uint8_t)s->value;
        write_all(client, rsp, sizeof(rsp));
    }
}

int main(int argc, char **argv)
{
    static struct status_reader status;

    if (argc != 4) {
        fprintf(stderr, "usage: floor_forwarder STATUS_PORT COMMAND_PORT MODBUS_PORT\n");
        return 2;
    }
    int listener = listen_port((unsigned)atoi(argv[3]));
    int status_fd = connect_port((unsigned)atoi(argv[1]));
    int robot = connect_port((unsigned)atoi(argv[2]));
    int ep = epoll_create1(0);
    watch(ep, listener);
    watch(ep, status_fd);
    watch(ep, robot);
    for (;;) {
        struct epoll_event ev[8];
        int n = epoll_wait(ep, ev, 8, -1);
        for (int i = 0; i < n; i++) {
            int fd = ev[i].data.fd;
            if (fd == listener) {
                int client = accept(listener, NULL, NULL);
                int one = 1;
                setsockopt(client, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
                watch(ep, client);
            } else if (fd == status_fd) {
                take_status(&status, fd);
            } else if (fd == robot) {
                drop_reply(robot);
            } else {
                serve(fd, robot, &status);
            }
        }
    }
}
