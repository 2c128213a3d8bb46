/* SPDX-License-Identifier: MIT */
/*
 * test_robot_link.c - the robot link on a real libuv loop against an
 * in-process TCP server: silence detection must not mistake the time spent
 * handling a large document for silence from the robot; a connection
 * dropped for a fault ends with an RST, never a FIN; keepalive and
 * TCP_USER_TIMEOUT are set on the socket; with newest_only, a burst of
 * documents hands over the newest and every one that changes a mark.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <sys/socket.h>
#include <stdlib.h>
#include <string.h>
#include <uv.h>

#include "log.h"
#include "robot_link.h"
#include "status.h"

/*
 * The link's silence limit. Under qemu-user (JAKAGW_ARCH set, as make test
 * ARCH=... runs the unit tests) on a loaded machine, timers and the
 * emulated code run several times slower: every time in these tests is a
 * multiple of it, so it is longer there (main()).
 */
static unsigned silence_ms = 150;
#define DOC "{\"len\": 19, \"n\": 1}"
#define BURST_DOCS 40

struct fixture {
    uv_loop_t loop;
    uv_tcp_t server;
    uv_tcp_t peer;
    bool peer_open;
    uv_timer_t pusher;
    uv_timer_t stop;
    struct robot_link link;
    int objects;
    int connected;
    unsigned busy_ms; /* how long the first object's handling takes */
    int pushes;
    int push_limit; /* 0: no limit */
    char peer_buf[4096];
    ssize_t peer_end;  /* how the first connection ended for the robot: 0 not */
    int keepalive, keepidle, keepintvl, user_timeout; /* on the link's socket */
    /* newest_only: a burst written at once on accept; what was handed over. */
    bool newest_only;
    char burst[8192];
    size_t burst_size;
    int handed[BURST_DOCS];
    int handed_count;
    struct status_marks marks; /* of the last document seen */
};

static void on_peer_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf)
{
    struct fixture *fx = h->data;
    (void)suggested;
    *buf = uv_buf_init(fx->peer_buf, sizeof(fx->peer_buf));
}

/* The robot's side of the first connection: how did it end? */
static void on_peer_read(uv_stream_t *s, ssize_t nread, const uv_buf_t *buf)
{
    struct fixture *fx = s->data;
    (void)buf;
    if (nread < 0 && fx->peer_end == 0) {
        fx->peer_end = nread;
        uv_read_stop(s);
    }
}

static void on_written(uv_write_t *req, int status)
{
    (void)status;
    free(req);
}

/* The robot pushes a document every silence_ms / 3. */
static void push(uv_timer_t *t)
{
    struct fixture *fx = t->data;
    if (!fx->peer_open || (fx->push_limit && fx->pushes >= fx->push_limit))
        return;
    fx->pushes++;
    uv_write_t *req = malloc(sizeof(*req));
    uv_buf_t buf = uv_buf_init((char *)DOC, (unsigned)strlen(DOC));
    /* On a loaded machine a push may come after the link reset the
     * connection (EPIPE): the end itself is what on_peer_read records. */
    int rc = uv_write(req, (uv_stream_t *)&fx->peer, &buf, 1, on_written);
    if (rc != 0) {
        assert_true(rc == UV_EPIPE || rc == UV_ECONNRESET);
        free(req);
    }
}

static void on_peer(uv_stream_t *server, int status)
{
    struct fixture *fx = server->data;
    assert_int_equal(status, 0);
    if (fx->peer_open) {
        /* A reconnect: accept and drop, the test counts connections. */
        uv_tcp_t *extra = malloc(sizeof(*extra));
        uv_tcp_init(&fx->loop, extra);
        uv_accept(server, (uv_stream_t *)extra);
        uv_close((uv_handle_t *)extra, (uv_close_cb)free);
        return;
    }
    uv_tcp_init(&fx->loop, &fx->peer);
    fx->peer.data = fx;
    assert_int_equal(uv_accept(server, (uv_stream_t *)&fx->peer), 0);
    fx->peer_open = true;
    assert_int_equal(uv_read_start((uv_stream_t *)&fx->peer, on_peer_alloc, on_peer_read), 0);
    if (fx->burst_size) {
        uv_buf_t buf = uv_buf_init(fx->burst, (unsigned)fx->burst_size);
        assert_int_equal(uv_try_write((uv_stream_t *)&fx->peer, &buf, 1), (int)fx->burst_size);
    }
}

static void on_object(struct robot_link *link, const char *json, size_t size)
{
    struct fixture *fx = link->user;
    if (fx->newest_only) {
        status_marks_of(json, size, &fx->marks);
        const char *n = strstr(json, "\"n\": ");
        assert_non_null(n);
        assert_true(fx->handed_count < BURST_DOCS);
        fx->handed[fx->handed_count++] = atoi(n + 5);
    }
    if (fx->objects++ == 0 && fx->busy_ms) {
        /* Stands for parsing a large document: the loop is busy. */
        uint64_t until = uv_hrtime() + (uint64_t)fx->busy_ms * 1000000;
        while (uv_hrtime() < until)
            ;
    }
}

/* As the gateway decides: handed over all the same when a mark changes. */
static bool on_superseded(struct robot_link *link, const char *json, size_t size)
{
    struct fixture *fx = link->user;
    struct status_marks marks;
    status_marks_of(json, size, &marks);
    bool changes = status_marks_differ(&marks, &fx->marks);
    fx->marks = marks;
    return changes;
}

static void on_state(struct robot_link *link, enum robot_link_state state)
{
    struct fixture *fx = link->user;
    if (state != ROBOT_LINK_CONNECTED || fx->connected++ > 0)
        return;
    uv_os_fd_t fd;
    socklen_t n = sizeof(int);
    assert_int_equal(uv_fileno((uv_handle_t *)&link->tcp, &fd), 0);
    assert_int_equal(getsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &fx->keepalive, &n), 0);
    assert_int_equal(getsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &fx->keepidle, &n), 0);
    assert_int_equal(getsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &fx->keepintvl, &n), 0);
    assert_int_equal(getsockopt(fd, IPPROTO_TCP, TCP_USER_TIMEOUT, &fx->user_timeout, &n), 0);
}

static void on_link_closed(struct robot_link *link)
{
    (void)link;
}

static void close_all(uv_timer_t *t)
{
    struct fixture *fx = t->data;
    robot_link_close(&fx->link, on_link_closed);
    uv_close((uv_handle_t *)&fx->server, NULL);
    uv_close((uv_handle_t *)&fx->pusher, NULL);
    uv_close((uv_handle_t *)&fx->stop, NULL);
    if (fx->peer_open)
        uv_close((uv_handle_t *)&fx->peer, NULL);
}

static void run_link(struct fixture *fx, unsigned run_ms)
{
    struct sockaddr_in addr;
    struct sockaddr_storage bound;
    int len = sizeof(bound);

    assert_int_equal(uv_loop_init(&fx->loop), 0);
    uv_tcp_init(&fx->loop, &fx->server);
    fx->server.data = fx;
    uv_ip4_addr("127.0.0.1", 0, &addr);
    assert_int_equal(uv_tcp_bind(&fx->server, (const struct sockaddr *)&addr, 0), 0);
    assert_int_equal(uv_listen((uv_stream_t *)&fx->server, 8, on_peer), 0);
    uv_tcp_getsockname(&fx->server, (struct sockaddr *)&bound, &len);

    struct robot_link_config cfg = {
        .name = "status",
        .host = "127.0.0.1",
        .port = ntohs(((struct sockaddr_in *)&bound)->sin_port),
        .connect_timeout_ms = 1000,
        .reconnect_min_ms = 50,
        .reconnect_max_ms = 100,
        .silence_timeout_ms = silence_ms,
        .user_timeout_ms = 1500,
        .max_object = 4096,
        .newest_only = fx->newest_only,
    };
    struct robot_link_callbacks cb = {.on_object = on_object, .on_state = on_state,
                                      .on_superseded = on_superseded};
    assert_int_equal(robot_link_init(&fx->loop, &fx->link, &cfg, &cb, fx), 0);
    assert_int_equal(robot_link_start(&fx->link), 0);
    uv_timer_init(&fx->loop, &fx->pusher);
    uv_timer_init(&fx->loop, &fx->stop);
    fx->pusher.data = fx->stop.data = fx;
    uv_timer_start(&fx->pusher, push, silence_ms / 3, silence_ms / 3);
    uv_timer_start(&fx->stop, close_all, run_ms, 0);
    uv_run(&fx->loop, UV_RUN_DEFAULT);
    /* Every handle closed: the loop closes clean. */
    assert_int_equal(uv_loop_close(&fx->loop), 0);
}

/*
 * The first document takes 2.5 x the silence limit to handle. The robot
 * kept sending meanwhile, so the link must stay up: one connection only.
 */
static void long_handling_is_not_silence(void **state)
{
    (void)state;
    struct fixture fx;
    memset(&fx, 0, sizeof(fx));
    fx.busy_ms = silence_ms * 5 / 2;
    run_link(&fx, silence_ms * 6);
    assert_true(fx.objects > 3);
    assert_int_equal(fx.connected, 1);
}

/* A robot that goes quiet after two documents is restarted: the check works. */
static void real_silence_restarts(void **state)
{
    (void)state;
    struct fixture fx;
    memset(&fx, 0, sizeof(fx));
    fx.push_limit = 2;
    run_link(&fx, silence_ms * 6);
    assert_int_equal(fx.objects, 2);
    assert_true(fx.connected >= 2);
}

/*
 * The robot goes quiet, the link gives up on the connection: the robot
 * sees it reset (RST), not closed (FIN), so nothing the gateway had queued
 * could reach it later. The socket had keepalive and TCP_USER_TIMEOUT.
 */
static void fault_close_is_abortive(void **state)
{
    (void)state;
    struct fixture fx;
    memset(&fx, 0, sizeof(fx));
    fx.push_limit = 2;
    run_link(&fx, silence_ms * 4);
    assert_true(fx.connected >= 2);
    assert_int_equal(fx.peer_end, UV_ECONNRESET);
    assert_int_equal(fx.keepalive, 1);
    assert_int_equal(fx.keepidle, ROBOT_LINK_KEEPALIVE_IDLE_S);
    assert_int_equal(fx.keepintvl, ROBOT_LINK_KEEPALIVE_INTERVAL_S);
    assert_int_equal(fx.user_timeout, 1500);
}

/* Document n of a burst: "enabled" is true for 17 and 18 only, "inpos"
 * changes at 30 and stays; "len" frames each. */
static size_t burst_document(char *out, size_t room, int n)
{
    char body[128];
    int body_size = snprintf(body, sizeof(body), ", \"n\": %d, \"enabled\": %s, \"inpos\": %d, "
                             "\"joint_actual_position\": [%d.5, 0, 0, 0, 0, 0]}",
                             n, n == 17 || n == 18 ? "true" : "false", n >= 30, n);
    /* '{"len": ' + its digits + body: three digits always. */
    int size = (int)strlen("{\"len\": 000") + body_size;
    return (size_t)snprintf(out, room, "{\"len\": %03d%s", size, body);
}

/*
 * 40 documents arrive at once: only the newest is handed over, and every
 * one whose marks differ from the document before it (the two that
 * enable, the one after that disables, the one that reaches position),
 * so no transition is lost; positions alone change nothing to hand over.
 */
static void burst_hands_over_the_newest_and_every_transition(void **state)
{
    (void)state;
    struct fixture fx;
    memset(&fx, 0, sizeof(fx));
    fx.newest_only = true;
    fx.push_limit = -1; /* the pusher stays quiet */
    for (int n = 0; n < BURST_DOCS; n++)
        fx.burst_size += burst_document(fx.burst + fx.burst_size,
                                        sizeof(fx.burst) - fx.burst_size, n);
    run_link(&fx, silence_ms * 2);
    assert_true(fx.handed_count >= 4);
    assert_int_equal(fx.handed[fx.handed_count - 1], BURST_DOCS - 1);
    bool seen[BURST_DOCS] = {false};
    for (int i = 0; i < fx.handed_count; i++) {
        assert_true(i == 0 || fx.handed[i] > fx.handed[i - 1]); /* in order */
        seen[fx.handed[i]] = true;
    }
    assert_true(seen[17] && seen[19] && seen[30]);
    /* One read took the burst: the rest were superseded unhandled. */
    assert_int_equal(fx.handed_count + (int)fx.link.superseded, BURST_DOCS);
    assert_true(fx.link.superseded >= 30);
}

int main(void)
{
    const char *arch = getenv("JAKAGW_ARCH");
    if (arch && *arch)
        silence_ms = 450;
    signal(SIGPIPE, SIG_IGN); /* a write to a closed peer must not end the test */
    log_set_level(LOG_LEVEL_ERR);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(long_handling_is_not_silence),
        cmocka_unit_test(real_silence_restarts),
        cmocka_unit_test(fault_close_is_abortive),
        cmocka_unit_test(burst_hands_over_the_newest_and_every_transition),
    };
    return cmocka_run_group_tests_name("robot_link", tests, NULL, NULL);
}
