/* SPDX-License-Identifier: MIT */
/*
 * ref_slave.c - a reference Modbus TCP slave built the plain libmodbus way,
 * for comparison with jakagw under abuse (tests/integration/test_abuse.py).
 *
 * One libmodbus context, one select() loop over the listening socket and
 * every client; for a readable client, modbus_receive() reads one whole
 * request (blocking until it is complete, or libmodbus's byte timeout) and
 * modbus_reply() answers it from a mapping of the given sizes. A receive
 * error closes that client. There is no connection limit, idle timeout or
 * write restriction: this is what a gateway gets from libmodbus alone.
 *
 *   ref_slave [--bind ADDR] [--port N] [--bits N] [--input-bits N]
 *             [--registers N] [--input-registers N] [--max-seconds N]
 *
 * It prints "ref_slave: listening on ADDR:PORT" once it accepts
 * connections, and stops on SIGTERM or SIGINT, or after --max-seconds.
 */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

static volatile sig_atomic_t stop_requested;

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

static int parse_count(const char *flag, const char *text, long max, int *out)
{
    char *end;
    long v;

    errno = 0;
    v = strtol(text, &end, 10);
    if (errno || *end != '\0' || v < 0 || v > max) {
        fprintf(stderr, "ref_slave: %s: '%s' must be 0..%ld\n", flag, text, max);
        return -1;
    }
    *out = (int)v;
    return 0;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

int main(int argc, char **argv)
{
    const char *bind_addr = "127.0.0.1";
    int port = 1502, bits = 10000, input_bits = 10000, registers = 10000,
        input_registers = 10000, max_seconds = 0;
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    struct sigaction sa;
    fd_set clients;
    int listener, max_fd, status = 0;

    for (int i = 1; i < argc; i++) {
        const char *flag = argv[i];
        int *target = NULL;
        long max = 65536;
        if (i + 1 >= argc) {
            fprintf(stderr, "ref_slave: %s needs a value\n", flag);
            return 2;
        }
        if (strcmp(flag, "--bind") == 0) {
            bind_addr = argv[++i];
            continue;
        }
        if (strcmp(flag, "--port") == 0) {
            target = &port;
            max = 65535;
        } else if (strcmp(flag, "--bits") == 0) {
            target = &bits;
        } else if (strcmp(flag, "--input-bits") == 0) {
            target = &input_bits;
        } else if (strcmp(flag, "--registers") == 0) {
            target = &registers;
        } else if (strcmp(flag, "--input-registers") == 0) {
            target = &input_registers;
        } else if (strcmp(flag, "--max-seconds") == 0) {
            target = &max_seconds;
            max = 86400;
        } else {
            fprintf(stderr, "ref_slave: unknown option '%s'\n", flag);
            return 2;
        }
        if (parse_count(flag, argv[++i], max, target) < 0)
            return 2;
    }

    /* Without SA_RESTART: a signal interrupts select() and modbus_receive(). */
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    modbus_t *ctx = modbus_new_tcp(bind_addr, port);
    modbus_mapping_t *map = modbus_mapping_new(bits, input_bits, registers, input_registers);
    if (!ctx || !map) {
        fprintf(stderr, "ref_slave: %s\n", modbus_strerror(errno));
        return 1;
    }
    listener = modbus_tcp_listen(ctx, 64);
    if (listener < 0) {
        fprintf(stderr, "ref_slave: cannot listen on %s:%d: %s\n", bind_addr, port,
                modbus_strerror(errno));
        modbus_mapping_free(map);
        modbus_free(ctx);
        return 1;
    }
    printf("ref_slave: listening on %s:%d\n", bind_addr, port);
    fflush(stdout);

    FD_ZERO(&clients);
    max_fd = listener;
    double deadline = max_seconds ? now_s() + max_seconds : 0;
    while (!stop_requested && (!deadline || now_s() < deadline)) {
        fd_set readable = clients;
        struct timeval tv = {1, 0};
        FD_SET(listener, &readable);
        int n = select(max_fd + 1, &readable, NULL, NULL, &tv);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            fprintf(stderr, "ref_slave: select: %s\n", strerror(errno));
            status = 1;
            break;
        }
        for (int fd = 0; fd <= max_fd && n > 0 && !stop_requested; fd++) {
            if (!FD_ISSET(fd, &readable))
                continue;
            n--;
            if (fd == listener) {
                int s = listener;
                /* modbus_tcp_accept() takes the listening socket by pointer. */
                int client = modbus_tcp_accept(ctx, &s);
                if (client < 0)
                    continue;
                if (client >= FD_SETSIZE) {
                    close(client); /* select() cannot watch it */
                    continue;
                }
                FD_SET(client, &clients);
                if (client > max_fd)
                    max_fd = client;
                continue;
            }
            modbus_set_socket(ctx, fd);
            int rc = modbus_receive(ctx, query);
            if (rc > 0) {
                modbus_reply(ctx, query, rc, map);
            } else if (rc < 0) {
                /* Closed by the client, a timeout inside a request, or a
                 * request libmodbus cannot frame: the connection goes. */
                close(fd);
                FD_CLR(fd, &clients);
            }
        }
    }

    for (int fd = 0; fd <= max_fd; fd++)
        if (FD_ISSET(fd, &clients))
            close(fd);
    close(listener);
    modbus_mapping_free(map);
    modbus_free(ctx);
    return status;
}
