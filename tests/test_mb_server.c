/* SPDX-License-Identifier: MIT */
/*
 * test_mb_server.c - the Modbus server on a real loop and real sockets:
 * a connection that cannot be given memory is closed, and both listeners
 * keep serving the PLCs that come next; a PLC's socket is set to notice a
 * silent peer in seconds; a client with no socket (the serial line's) is
 * answered through its transport, counted, released when idle, and never
 * evicted for a TCP newcomer.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "mb_server.h"
#include "regmap.h"

static unsigned failures_left;

/* calloc, failing the first 'failures_left' calls. */
static void *calloc_failing(size_t count, size_t size)
{
    if (failures_left > 0) {
        failures_left--;
        return NULL;
    }
    return calloc(count, size);
}

struct fixture {
    uv_loop_t loop;
    struct regmap map;
    struct regmap_image img;
    struct mb_server srv;
    bool closed;
};

static int setup(void **state)
{
    static struct fixture f;
    struct mb_server_config cfg = {.bind = "127.0.0.1", .port = 0, .max_clients = 8,
                                   .frame_timeout_ms = 1000, .unit_id = -1};
    struct mb_server_hooks hooks = {0};

    memset(&f, 0, sizeof(f));
    assert_int_equal(uv_loop_init(&f.loop), 0);
    assert_int_equal(regmap_init(&f.map), 0);
    assert_int_equal(regmap_image_init(&f.img, &f.map, REGMAP_HIGH_WORD_FIRST), 0);
    hooks.user = &f;
    assert_int_equal(mb_server_start(&f.loop, &f.srv, &cfg, &f.img, &hooks), 0);
    f.srv.calloc_client = calloc_failing;
    *state = &f;
    return 0;
}

static void on_server_closed(struct mb_server *srv)
{
    struct fixture *f = srv->hooks.user;
    f->closed = true;
}

static int teardown(void **state)
{
    struct fixture *f = *state;
    mb_server_close(&f->srv, on_server_closed);
    while (!f->closed)
        uv_run(&f->loop, UV_RUN_ONCE);
    regmap_image_free(&f->img);
    regmap_free(&f->map);
    /* Every handle closed: a leaked one fails here. */
    assert_int_equal(uv_loop_close(&f->loop), 0);
    return 0;
}

static int connect_to(int port)
{
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0);

    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    assert_true(fd >= 0);
    int rc = connect(fd, (struct sockaddr *)&a, sizeof(a));
    assert_true(rc == 0 || errno == EINPROGRESS);
    return fd;
}

static int connect_client(struct fixture *f)
{
    return connect_to(mb_server_port(&f->srv));
}

/*
 * Runs the loop until 'fd' can be read (data or end of stream) or 2 s pass.
 * Returns what read() gave: bytes, 0 at end of stream, -1 on timeout.
 */
static ssize_t pump_until_readable(struct fixture *f, int fd, uint8_t *buf, size_t size)
{
    for (int i = 0; i < 2000; i++) {
        uv_run(&f->loop, UV_RUN_NOWAIT);
        struct pollfd p = {.fd = fd, .events = POLLIN};
        if (poll(&p, 1, 1) == 1) {
            ssize_t n = read(fd, buf, size);
            if (n >= 0 || errno != EAGAIN)
                return n < 0 ? 0 : n; /* a reset is an end too */
        }
    }
    return -1;
}

static void write_all(int fd, const uint8_t *data, size_t size)
{
    for (int i = 0; i < 100 && size > 0; i++) {
        ssize_t n = write(fd, data, size);
        if (n > 0) {
            data += n;
            size -= (size_t)n;
        } else {
            struct pollfd p = {.fd = fd, .events = POLLOUT};
            poll(&p, 1, 10);
        }
    }
    assert_int_equal(size, 0);
}

/* Runs the loop until the server has no client left (at most 1 s). */
static void pump_until_no_client(struct fixture *f)
{
    for (int i = 0; i < 5000 && f->srv.stats.clients; i++)
        uv_run(&f->loop, UV_RUN_NOWAIT), usleep(1000);
}

/* FC04, input register 0, one register. */
static const uint8_t read_magic[] = {0, 1, 0, 0, 0, 6, 1, 4, 0, 0, 0, 1};

static void a_connection_without_memory_is_closed_and_the_next_is_served(void **state)
{
    struct fixture *f = *state;
    uint8_t buf[64];
    int refused[3];

    /* Three connections at once, while no memory can be had. */
    failures_left = 1000;
    for (int i = 0; i < 3; i++)
        refused[i] = connect_client(f);
    for (int i = 0; i < 3; i++) {
        ssize_t n = pump_until_readable(f, refused[i], buf, sizeof(buf));
        assert_int_equal(n, 0); /* closed, not left hanging */
        close(refused[i]);
    }
    assert_int_equal(f->srv.stats.refused_no_memory, 3);
    assert_int_equal(f->srv.stats.clients, 0);
    failures_left = 0; /* memory again */

    /* The listener still accepts, and the newcomer is answered. */
    int fd = connect_client(f);
    write_all(fd, read_magic, sizeof(read_magic));
    ssize_t n = pump_until_readable(f, fd, buf, sizeof(buf));
    assert_int_equal(n, 11);
    assert_int_equal(buf[7], 4); /* FC04 answered, not an exception */
    assert_int_equal(buf[8], 2); /* one register */
    close(fd);
    /* Let the server see the close before it is torn down. */
    pump_until_no_client(f);
}

/*
 * Both listeners wait for the same refusal to close: the plain one with a
 * connection it could not give memory to, the second one likewise. Memory
 * comes back as the first is taken up; the second must be taken up too,
 * or libuv never polls it again and its port is dead for good.
 */
static void both_listeners_resume_after_refusals(void **state)
{
    struct fixture *f = *state;
    uint8_t buf[64];
    int fds[4];

    assert_int_equal(mb_server_listen(&f->srv, "127.0.0.1", 0, 0, &mb_transport_plain, NULL), 0);
    int ports[2] = {mb_server_port(&f->srv), mb_server_listen_port(&f->srv)};
    assert_true(ports[1] > 0);
    /* Two on each port, all waiting before the loop runs: whichever
     * listener goes first refuses one and holds its second; the other
     * holds its first. Three allocations fail: memory is back for the
     * next one. */
    failures_left = 3;
    for (int i = 0; i < 4; i++) {
        fds[i] = connect_to(ports[i % 2]);
        write_all(fds[i], read_magic, sizeof(read_magic));
    }
    for (int i = 0; i < 4; i++) {
        ssize_t n = pump_until_readable(f, fds[i], buf, sizeof(buf));
        /* Closed (refused) or answered; never left hanging. */
        assert_true(n == 0 || n == 11);
        close(fds[i]);
    }
    assert_true(f->srv.stats.refused_no_memory >= 1);
    for (int round = 0; round < 2; round++) {
        for (int i = 0; i < 2; i++) {
            int fd = connect_to(ports[i]);
            write_all(fd, read_magic, sizeof(read_magic));
            assert_int_equal(pump_until_readable(f, fd, buf, sizeof(buf)), 11);
            assert_int_equal(buf[7], 4);
            close(fd);
        }
    }
    pump_until_no_client(f);
}

/* The accepted socket of the server whose peer is the local end 'fd'. */
static int server_side_of(int fd)
{
    struct sockaddr_in mine, peer;
    socklen_t len = sizeof(mine);

    assert_int_equal(getsockname(fd, (struct sockaddr *)&mine, &len), 0);
    for (int s = 3; s < 1024; s++) {
        len = sizeof(peer);
        if (s != fd && getpeername(s, (struct sockaddr *)&peer, &len) == 0 &&
            peer.sin_family == AF_INET && peer.sin_port == mine.sin_port)
            return s;
    }
    return -1;
}

static int tcp_option(int fd, int level, int name)
{
    int v = -1;
    socklen_t len = sizeof(v);
    assert_int_equal(getsockopt(fd, level, name, &v, &len), 0);
    return v;
}

/*
 * A PLC pulled off the network says nothing: keepalive (2 s, then 1 s,
 * 3 probes) and TCP_USER_TIMEOUT (5 s) end its connection in about 5 s,
 * which frees its slot and what it owned.
 */
static void a_plc_socket_notices_a_silent_peer_in_seconds(void **state)
{
    struct fixture *f = *state;
    uint8_t buf[64];
    int fd = connect_client(f);

    write_all(fd, read_magic, sizeof(read_magic));
    assert_int_equal(pump_until_readable(f, fd, buf, sizeof(buf)), 11);
    int s = server_side_of(fd);
    assert_true(s >= 0);
    assert_int_equal(tcp_option(s, SOL_SOCKET, SO_KEEPALIVE), 1);
    assert_int_equal(tcp_option(s, IPPROTO_TCP, TCP_KEEPIDLE), MB_SERVER_KEEPALIVE_IDLE_S);
    assert_int_equal(tcp_option(s, IPPROTO_TCP, TCP_KEEPINTVL), MB_SERVER_KEEPALIVE_INTERVAL_S);
    assert_int_equal(tcp_option(s, IPPROTO_TCP, TCP_KEEPCNT), MB_SERVER_KEEPALIVE_COUNT);
    assert_int_equal(tcp_option(s, IPPROTO_TCP, TCP_USER_TIMEOUT), MB_SERVER_USER_TIMEOUT_MS);
    assert_true(MB_SERVER_KEEPALIVE_IDLE_S +
                    MB_SERVER_KEEPALIVE_INTERVAL_S * MB_SERVER_KEEPALIVE_COUNT <= 5);
    close(fd);
    pump_until_no_client(f);
}

/* A transport with no socket: what the server sent, and whether it closed. */
struct line {
    uint8_t out[512];
    size_t out_size;
    unsigned closes;
    struct mb_client *client;
};

static void line_output(void *state, struct mb_client *c, const uint8_t *data, size_t size)
{
    struct line *l = state;
    (void)c;
    assert_true(l->out_size + size <= sizeof(l->out));
    memcpy(l->out + l->out_size, data, size);
    l->out_size += size;
}

static void line_closed(void *state, struct mb_client *c, bool was_pending)
{
    struct line *l = state;
    assert_ptr_equal(c, l->client);
    assert_false(was_pending);
    l->closes++;
    l->client = NULL;
}

static const struct mb_transport line_transport = {
    .name = "line",
    .output = line_output,
    .closed = line_closed,
};

static void line_request(struct line *l, const uint8_t *req, size_t size)
{
    size_t room;
    uint8_t *into = mb_client_space(l->client, &room);
    assert_true(room >= size);
    memcpy(into, req, size);
    mb_client_received(l->client, size);
}

static void a_client_without_a_socket_is_served_counted_and_released(void **state)
{
    struct fixture *f = *state;
    /* Static: the server's close in teardown still calls its transport. */
    static struct line l;
    /* The image as it is (no gateway fills it here): input register 0. */
    uint16_t ir0 = f->img.mb->tab_input_registers[0];
    const uint8_t magic_reply[] = {0, 1, 0, 0, 0, 5, 1, 4, 2, (uint8_t)(ir0 >> 8), (uint8_t)ir0};

    memset(&l, 0, sizeof(l));
    /* An idle time of 1 s: long enough that the TCP newcomer below is
     * accepted first even under qemu-user on a loaded machine (at 100 ms
     * the line was sometimes released before the accept). */
    assert_int_equal(mb_server_attach(&f->srv, "line:test", &line_transport, &l,
                                      REGMAP_RIGHTS_NONE, 1000, &l.client),
                     0);
    assert_non_null(l.client);
    assert_int_equal(f->srv.stats.clients, 1);
    assert_string_equal(mb_client_peer(l.client), "line:test");
    /* Answered at once, through the transport. */
    line_request(&l, read_magic, sizeof(read_magic));
    assert_int_equal(l.out_size, sizeof(magic_reply));
    assert_memory_equal(l.out, magic_reply, sizeof(magic_reply));
    assert_int_equal(f->srv.stats.requests, 1);

    /* At max_clients, a TCP newcomer is admitted; the line is not evicted. */
    f->srv.cfg.max_clients = 1;
    int fd = connect_client(f);
    for (int i = 0; i < 5000 && f->srv.stats.clients < 2; i++)
        uv_run(&f->loop, UV_RUN_NOWAIT), usleep(1000);
    assert_int_equal(f->srv.stats.clients, 2);
    assert_int_equal(l.closes, 0);
    assert_int_equal(f->srv.stats.evictions, 0);
    close(fd);

    /* No request for its idle time: released, and its transport hears it. */
    for (int i = 0; i < 5000 && l.closes == 0; i++)
        uv_run(&f->loop, UV_RUN_NOWAIT), usleep(1000);
    assert_int_equal(l.closes, 1);
    assert_null(l.client);
    pump_until_no_client(f);
    assert_int_equal(f->srv.stats.clients, 0);

    /* Attached again, then the server closes with it open (teardown). */
    assert_int_equal(mb_server_attach(&f->srv, "line:test", &line_transport, &l,
                                      REGMAP_RIGHTS_NONE, 0, &l.client),
                     0);
    assert_int_equal(f->srv.stats.clients, 1);
}

/*
 * The line is not a TCP client for limits: attached at max_clients (again
 * and again, as after each idle time) it takes no slot and evicts no PLC;
 * a TCP newcomer then displaces a TCP client, never the line.
 */
static void a_line_at_max_clients_takes_no_slot_and_evicts_no_one(void **state)
{
    struct fixture *f = *state;
    static struct line l;

    memset(&l, 0, sizeof(l));
    f->srv.cfg.max_clients = 1;
    int plc = connect_client(f);
    for (int i = 0; i < 5000 && f->srv.stats.clients < 1; i++)
        uv_run(&f->loop, UV_RUN_NOWAIT), usleep(1000);
    assert_int_equal(f->srv.stats.clients, 1);
    for (int round = 0; round < 5; round++) {
        assert_int_equal(mb_server_attach(&f->srv, "line:test", &line_transport, &l,
                                          REGMAP_RIGHTS_NONE, 20, &l.client),
                         0);
        assert_int_equal(f->srv.stats.clients, 2);
        assert_int_equal(f->srv.stats.evictions, 0);
        /* Idle: released, to attach again. */
        for (int i = 0; i < 5000 && l.client; i++)
            uv_run(&f->loop, UV_RUN_NOWAIT), usleep(1000);
        assert_null(l.client);
    }
    assert_int_equal(f->srv.stats.evictions, 0);
    /* The PLC is still served. */
    assert_int_equal(write(plc, read_magic, sizeof(read_magic)), (ssize_t)sizeof(read_magic));
    uint8_t reply[64];
    ssize_t got = 0;
    for (int i = 0; i < 1000 && got <= 0; i++) {
        uv_run(&f->loop, UV_RUN_NOWAIT);
        got = recv(plc, reply, sizeof(reply), MSG_DONTWAIT);
        if (got <= 0)
            usleep(1000);
    }
    assert_true(got >= 9);
    /* With the line attached, a second PLC displaces the first, not the line. */
    assert_int_equal(mb_server_attach(&f->srv, "line:test", &line_transport, &l,
                                      REGMAP_RIGHTS_NONE, 0, &l.client),
                     0);
    int second = connect_client(f);
    for (int i = 0; i < 500 && f->srv.stats.evictions < 1; i++)
        uv_run(&f->loop, UV_RUN_NOWAIT), usleep(1000);
    assert_int_equal(f->srv.stats.evictions, 1);
    assert_non_null(l.client);
    assert_int_equal(l.closes, 5);
    close(plc);
    close(second);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(
            a_connection_without_memory_is_closed_and_the_next_is_served, setup, teardown),
        cmocka_unit_test_setup_teardown(both_listeners_resume_after_refusals, setup, teardown),
        cmocka_unit_test_setup_teardown(a_client_without_a_socket_is_served_counted_and_released,
                                        setup, teardown),
        cmocka_unit_test_setup_teardown(a_plc_socket_notices_a_silent_peer_in_seconds, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(a_line_at_max_clients_takes_no_slot_and_evicts_no_one,
                                        setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
