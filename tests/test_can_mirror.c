/* SPDX-License-Identifier: MIT */
/*
 * test_can_mirror.c - the CAN mirror's periods and its handling of a
 * troubled bus, with a fake sink and the test's own clock; the SocketCAN
 * sink's checks that need no CAN support in the kernel.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "can_mirror.h"
#include "log.h"

#define MAX_SENT 4096
#define SCRIPT 64

struct sent_frame {
    uint32_t id;
    uint8_t dlc;
    uint8_t data[8];
};

/* A sink whose answers the test scripts: each call takes the next scripted
   result (0 once the script runs out). */
struct fake {
    struct can_sink sink;
    int open_results[SCRIPT], send_results[SCRIPT], poll_results[SCRIPT];
    unsigned opens, sends, polls, closes;
    bool is_open;
    struct sent_frame sent[MAX_SENT];
    unsigned sent_count;
    char last_interface[IF_NAMESIZE];
};

static int next_result(const int *script, unsigned call)
{
    return call < SCRIPT ? script[call] : 0;
}

static int fake_open(struct can_sink *sink, const char *interface)
{
    struct fake *f = sink->user;
    assert_false(f->is_open);
    snprintf(f->last_interface, sizeof(f->last_interface), "%s", interface);
    int rc = next_result(f->open_results, f->opens++);
    f->is_open = rc == 0;
    return rc;
}

static int fake_send(struct can_sink *sink, uint32_t id, const uint8_t *data, uint8_t dlc)
{
    struct fake *f = sink->user;
    assert_true(f->is_open);
    int rc = next_result(f->send_results, f->sends++);
    if (rc == 0 && f->sent_count < MAX_SENT) {
        struct sent_frame *s = &f->sent[f->sent_count++];
        s->id = id;
        s->dlc = dlc;
        memset(s->data, 0, sizeof(s->data));
        memcpy(s->data, data, dlc);
    }
    return rc;
}

static int fake_poll(struct can_sink *sink)
{
    struct fake *f = sink->user;
    assert_true(f->is_open);
    return next_result(f->poll_results, f->polls++);
}

static void fake_close(struct can_sink *sink)
{
    struct fake *f = sink->user;
    f->closes++;
    f->is_open = false;
}

static const struct can_sink_ops fake_ops = {
    .open = fake_open, .send = fake_send, .poll_events = fake_poll, .close = fake_close,
};

static struct fake *new_fake(void)
{
    struct fake *f = calloc(1, sizeof(*f));
    assert_non_null(f);
    f->sink.ops = &fake_ops;
    f->sink.fd = -1;
    f->sink.user = f;
    return f;
}

/* The owner's side: a status with a few values, gateway values. */
struct owner {
    struct jaka_status status;
    double gw[GW_VALUE_COUNT];
    unsigned snapshots;
};

static void snapshot(void *user, struct can_inputs *in)
{
    struct owner *o = user;
    o->snapshots++;
    in->status = &o->status;
    in->gw = o->gw;
}

static struct owner *new_owner(void)
{
    struct owner *o = calloc(1, sizeof(*o));
    assert_non_null(o);
    o->status.joint_actual_position[0] = (struct status_num){12.5, true};
    o->status.enabled[0] = (struct status_num){1, true};
    o->gw[GW_status_fresh] = 1;
    return o;
}

static struct can_mirror_config config(void)
{
    struct can_mirror_config c = {.interface = "vcan0", .base_id = 0x500,
                                  .period_ms = 100, .groups = CAN_GROUPS_ALL};
    return c;
}

struct fixture {
    struct fake *fake;
    struct owner *owner;
    struct can_mirror mirror;
};

static int setup(void **state)
{
    struct fixture *fx = calloc(1, sizeof(*fx));
    struct can_mirror_config c = config();
    if (!fx)
        return -1;
    fx->fake = new_fake();
    fx->owner = new_owner();
    if (can_mirror_init(&fx->mirror, &c, &fx->fake->sink, snapshot, fx->owner))
        return -1;
    *state = fx;
    return 0;
}

static int teardown(void **state)
{
    struct fixture *fx = *state;
    can_mirror_release(&fx->mirror);
    assert_false(fx->fake->is_open);
    free(fx->fake);
    free(fx->owner);
    free(fx);
    return 0;
}

/* Counts lines of stderr that contain 'text' while 'fn' runs. */
static int stderr_fd = -1;
static FILE *captured;

static void capture_begin(void)
{
    fflush(stderr);
    captured = tmpfile();
    assert_non_null(captured);
    stderr_fd = dup(2);
    dup2(fileno(captured), 2);
}

static unsigned capture_count(const char *text)
{
    char line[1024];
    unsigned n = 0;

    fflush(stderr);
    dup2(stderr_fd, 2);
    close(stderr_fd);
    rewind(captured);
    while (fgets(line, sizeof(line), captured))
        n += strstr(line, text) != NULL;
    fclose(captured);
    return n;
}

static void sends_every_frame_each_period(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;

    assert_int_equal(fx->mirror.frames_per_period, can_map_frame_count);
    for (uint64_t t = 0; t < 5; t++)
        can_mirror_tick(&fx->mirror, 1000 + t * 100);
    assert_int_equal(f->opens, 1);
    assert_string_equal(f->last_interface, "vcan0");
    assert_int_equal(f->sent_count, 5 * can_map_frame_count);
    assert_int_equal(fx->mirror.stats.frames_sent, 5 * can_map_frame_count);
    assert_int_equal(fx->mirror.stats.frames_dropped, 0);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
    assert_int_equal(fx->owner->snapshots, 5);
    /* In table order, with their ids and lengths; the counter adds 1 a period. */
    for (unsigned p = 0; p < 5; p++) {
        for (unsigned i = 0; i < can_map_frame_count; i++) {
            const struct sent_frame *s = &f->sent[p * can_map_frame_count + i];
            assert_int_equal(s->id, 0x500 + can_map_frames[i].id_offset);
            assert_int_equal(s->dlc, can_map_frames[i].dlc);
            if (strcmp(can_map_frames[i].name, "JAKA_Health") == 0) {
                assert_int_equal(s->data[1], p); /* RollingCounter */
                assert_int_equal(s->data[0], 0x04); /* StatusFresh only */
            }
            if (strcmp(can_map_frames[i].name, "JAKA_Joints_1_2") == 0) {
                assert_int_equal(s->data[0] | s->data[1] << 8, 12500);
                assert_int_equal(s->data[7], 0x80); /* joint 2 not sent */
            }
        }
    }
}

static void rolling_counter_wraps(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    struct can_mirror_config c = config();

    c.groups = 1u << CAN_GROUP_health;
    can_mirror_release(&fx->mirror);
    assert_int_equal(can_mirror_init(&fx->mirror, &c, &f->sink, snapshot, fx->owner), 0);
    for (unsigned t = 0; t < 300; t++)
        can_mirror_tick(&fx->mirror, t * 100);
    assert_int_equal(f->sent_count, 300);
    for (unsigned t = 0; t < 300; t++)
        assert_int_equal(f->sent[t].data[1], t % 256);
}

static void groups_and_extended_ids(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    struct can_mirror_config c = config();

    c.groups = 1u << CAN_GROUP_state | 1u << CAN_GROUP_joints;
    c.extended_ids = true;
    c.base_id = 0x18FF0000;
    can_mirror_release(&fx->mirror);
    assert_int_equal(can_mirror_init(&fx->mirror, &c, &f->sink, snapshot, fx->owner), 0);
    assert_int_equal(fx->mirror.frames_per_period, 4);
    can_mirror_tick(&fx->mirror, 0);
    assert_int_equal(f->sent_count, 4);
    assert_int_equal(f->sent[0].id, CAN_SINK_EXTENDED | 0x18FF0000);
    assert_int_equal(f->sent[1].id, CAN_SINK_EXTENDED | 0x18FF0003);
    assert_int_equal(f->sent[3].id, CAN_SINK_EXTENDED | 0x18FF0005);
}

static void init_refuses_bad_configuration(void **state)
{
    struct fixture *fx = *state;
    struct can_mirror m;
    struct can_mirror_config c = config();

    c.base_id = CAN_MAX_STD_ID - can_map_max_offset();
    assert_int_equal(can_mirror_init(&m, &c, &fx->fake->sink, NULL, NULL), 0);
    c.base_id++;
    assert_int_equal(can_mirror_init(&m, &c, &fx->fake->sink, NULL, NULL), -EINVAL);
    c.extended_ids = true;
    assert_int_equal(can_mirror_init(&m, &c, &fx->fake->sink, NULL, NULL), 0);
    c.base_id = CAN_MAX_EXT_ID;
    assert_int_equal(can_mirror_init(&m, &c, &fx->fake->sink, NULL, NULL), -EINVAL);
    c = config();
    c.interface[0] = '\0';
    assert_int_equal(can_mirror_init(&m, &c, &fx->fake->sink, NULL, NULL), -EINVAL);
    c = config();
    c.period_ms = 0;
    assert_int_equal(can_mirror_init(&m, &c, &fx->fake->sink, NULL, NULL), -EINVAL);
    c = config();
    c.groups = 0;
    assert_int_equal(can_mirror_init(&m, &c, &fx->fake->sink, NULL, NULL), -EINVAL);
}

static void full_queue_drops_the_rest_of_the_period(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    const unsigned n = can_map_frame_count;

    /* Period 1: the 4th send finds the queue full; period 2 the 1st (EAGAIN). */
    f->send_results[3] = -ENOBUFS;
    f->send_results[4] = -EAGAIN;
    capture_begin();
    can_mirror_tick(&fx->mirror, 0);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_QUEUE_FULL);
    assert_int_equal(f->sends, 4); /* no more tries in that period */
    can_mirror_tick(&fx->mirror, 100);
    can_mirror_tick(&fx->mirror, 200);
    assert_int_equal(capture_count("transmit queue full (No buffer space available)"), 1);
    assert_int_equal(fx->mirror.stats.queue_full, 2);
    assert_int_equal(fx->mirror.stats.frames_sent, 3 + n);
    assert_int_equal(fx->mirror.stats.frames_dropped, (n - 3) + n);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
    assert_int_equal(f->opens, 1);
    assert_int_equal(f->closes, 0); /* the socket is kept */
    /* The health frame tells the receiver how many were lost (mod 65536). */
    const struct sent_frame *health = &f->sent[f->sent_count - n + 1];
    assert_int_equal(health->data[6] | health->data[7] << 8, 2 * n - 3);
    assert_int_equal(can_mirror_errors(&fx->mirror.stats), 2);
    can_mirror_clear_stats(&fx->mirror);
    assert_int_equal(fx->mirror.stats.frames_dropped, 0);
    assert_int_equal(can_mirror_errors(&fx->mirror.stats), 0);
}

static void interface_down_is_tried_every_period(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    const unsigned n = can_map_frame_count;

    for (unsigned i = 0; i < 5; i++)
        f->send_results[n + i] = -ENETDOWN;
    capture_begin();
    for (unsigned t = 0; t < 7; t++)
        can_mirror_tick(&fx->mirror, t * 100);
    unsigned down_lines = capture_count("vcan0: interface is down (Network is down)");
    assert_int_equal(down_lines, 1);
    assert_int_equal(fx->mirror.stats.interface_down, 5);
    assert_int_equal(fx->mirror.stats.frames_dropped, 5 * n);
    assert_int_equal(fx->mirror.stats.frames_sent, 2 * n);
    assert_int_equal(f->opens, 1);
    assert_int_equal(f->closes, 0);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
}

static void recovery_is_logged_once_with_the_loss(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    const unsigned n = can_map_frame_count;

    f->send_results[n] = -ENETDOWN;
    f->send_results[n + 1] = -ENETDOWN;
    char expect[64];

    capture_begin();
    for (unsigned t = 0; t < 4; t++)
        can_mirror_tick(&fx->mirror, t * 100);
    snprintf(expect, sizeof(expect), "sending again; %u frames dropped meanwhile", 2 * n);
    assert_int_equal(capture_count(expect), 1);
}

static void absent_interface_is_reopened_with_backoff(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    uint64_t open_times[16];
    unsigned opens_seen = 0;

    /* Absent at start for 7 tries, then it appears. */
    for (unsigned i = 0; i < 7; i++)
        f->open_results[i] = -ENODEV;
    capture_begin();
    for (uint64_t t = 0; t <= 8000; t += 10) {
        unsigned before = f->opens;
        can_mirror_tick(&fx->mirror, t);
        if (f->opens != before && opens_seen < 16)
            open_times[opens_seen++] = t;
    }
    assert_int_equal(capture_count("vcan0: no such interface (No such device)"), 1);
    assert_int_equal(opens_seen, 8);
    /* 100, 200, 400, 800, 1600 ms, then capped at 2000 ms. */
    const uint64_t expect[8] = {0, 100, 300, 700, 1500, 3100, 5100, 7100};
    assert_memory_equal(open_times, expect, sizeof(expect));
    assert_int_equal(fx->mirror.stats.interface_absent, 7);
    assert_int_equal(fx->mirror.stats.opens, 1);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
    /* Every period of the outage counts its frames as dropped. */
    assert_int_equal(fx->mirror.stats.frames_dropped, 710 * can_map_frame_count);
    assert_int_equal(fx->mirror.retry_delay_ms, 0);
}

static void vanished_interface_closes_and_reopens(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    const unsigned n = can_map_frame_count;

    f->send_results[n + 2] = -ENXIO; /* deleted while bound */
    f->open_results[1] = -ENODEV;    /* not back yet at the first retry */
    can_mirror_tick(&fx->mirror, 0);
    can_mirror_tick(&fx->mirror, 100);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_INTERFACE_ABSENT);
    assert_int_equal(f->closes, 1);
    can_mirror_tick(&fx->mirror, 150); /* before the retry time */
    assert_int_equal(f->opens, 1);
    can_mirror_tick(&fx->mirror, 200); /* retry: still absent */
    assert_int_equal(f->opens, 2);
    can_mirror_tick(&fx->mirror, 300); /* backing off 200 ms */
    assert_int_equal(f->opens, 2);
    can_mirror_tick(&fx->mirror, 400);
    assert_int_equal(f->opens, 3);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
    assert_int_equal(fx->mirror.stats.interface_absent, 2);
    assert_int_equal(fx->mirror.stats.opens, 2);
}

static void other_errors_reopen(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;

    f->open_results[0] = -EAFNOSUPPORT; /* no CAN in this kernel */
    f->poll_results[0] = -EIO;
    capture_begin();
    can_mirror_tick(&fx->mirror, 0);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_FAILED);
    can_mirror_tick(&fx->mirror, 100); /* opens; the poll fails */
    assert_int_equal(f->closes, 1);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_FAILED);
    can_mirror_tick(&fx->mirror, 300);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
    /* Two different errors, two lines. */
    assert_int_equal(capture_count("Address family not supported by protocol"), 1);
    assert_int_equal(fx->mirror.stats.other_errors, 2);
    assert_int_equal(fx->mirror.stats.frames_sent, can_map_frame_count);
}

static void bus_off_until_restarted(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;

    f->poll_results[1] = CAN_SINK_EVENT_BUS_OFF | CAN_SINK_EVENT_ERROR;
    f->send_results[2 * can_map_frame_count] = -ENOBUFS;
    f->poll_results[4] = CAN_SINK_EVENT_RESTARTED;
    capture_begin();
    can_mirror_tick(&fx->mirror, 0);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
    can_mirror_tick(&fx->mirror, 100);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_BUS_OFF);
    can_mirror_tick(&fx->mirror, 200); /* queue full while bus-off: still bus-off */
    assert_int_equal(fx->mirror.state, CAN_MIRROR_BUS_OFF);
    can_mirror_tick(&fx->mirror, 300);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_BUS_OFF);
    can_mirror_tick(&fx->mirror, 400);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
    assert_int_equal(capture_count("bus-off"), 1);
    assert_int_equal(fx->mirror.stats.bus_off, 1);
    assert_int_equal(fx->mirror.stats.queue_full, 1);
    assert_int_equal(f->closes, 0);
}

static void poll_reports_interface_down(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;

    /* The socket reports the interface went down; it is up again by now. */
    f->poll_results[1] = -ENETDOWN;
    can_mirror_tick(&fx->mirror, 0);
    can_mirror_tick(&fx->mirror, 100);
    assert_int_equal(fx->mirror.stats.interface_down, 1);
    assert_int_equal(fx->mirror.stats.frames_sent, 2 * can_map_frame_count);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_SENDING);
}

static void no_snapshot_sends_not_sent_markers(void **state)
{
    struct fixture *fx = *state;
    struct fake *f = fx->fake;
    struct can_mirror_config c = config();

    c.groups = 1u << CAN_GROUP_program;
    can_mirror_release(&fx->mirror);
    assert_int_equal(can_mirror_init(&fx->mirror, &c, &f->sink, NULL, NULL), 0);
    can_mirror_tick(&fx->mirror, 0);
    assert_int_equal(f->sent_count, 1);
    const uint8_t expect[8] = {0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0, 0};
    assert_memory_equal(f->sent[0].data, expect, 8);
}

/* ---- on a real loop ---- */

static void on_stop_timer(uv_timer_t *t)
{
    struct can_mirror *m = t->data;
    can_mirror_close(m, NULL);
    uv_close((uv_handle_t *)t, NULL);
}

static void runs_on_the_loop_and_closes_clean(void **state)
{
    struct fixture *fx = *state;
    struct can_mirror_config c = config();
    uv_loop_t loop;
    uv_timer_t stop;

    c.period_ms = 10;
    can_mirror_release(&fx->mirror);
    assert_int_equal(can_mirror_init(&fx->mirror, &c, &fx->fake->sink, snapshot, fx->owner), 0);
    assert_int_equal(uv_loop_init(&loop), 0);
    assert_int_equal(can_mirror_start(&loop, &fx->mirror), 0);
    assert_int_equal(can_mirror_start(&loop, &fx->mirror), -EALREADY);
    uv_timer_init(&loop, &stop);
    stop.data = &fx->mirror;
    uv_timer_start(&stop, on_stop_timer, 105, 0);
    uv_run(&loop, UV_RUN_DEFAULT);
    assert_int_equal(uv_loop_close(&loop), 0);
    /* At 0, 10, ... 100 ms: 11 periods, give or take one for timing. */
    unsigned periods = fx->owner->snapshots;
    assert_in_range(periods, 5, 12);
    assert_int_equal(fx->fake->sent_count, periods * can_map_frame_count);
    assert_false(fx->fake->is_open);
    assert_int_equal(fx->mirror.state, CAN_MIRROR_OFF);
}

/* ---- the SocketCAN sink, without a CAN interface ---- */

static void socketcan_sink_without_interface(void **state)
{
    (void)state;
    struct can_sink sink;
    const uint8_t data[8] = {0};

    can_sink_socketcan_init(&sink);
    assert_int_equal(sink.fd, -1);
    assert_int_equal(sink.ops->open(&sink, "jakagw-none0"), -ENODEV);
    assert_int_equal(sink.fd, -1);
    assert_int_equal(sink.ops->send(&sink, 0x500, data, 8), -EBADF);
    assert_int_equal(sink.ops->poll_events(&sink), -EBADF);
    sink.ops->close(&sink);
    /* The loopback interface exists; whether CAN sockets do depends on the
       kernel: either it opens, or the error is a clean negative errno. */
    int rc = sink.ops->open(&sink, "lo");
    if (rc == 0) {
        assert_true(sink.fd >= 0);
        assert_int_equal(sink.ops->send(&sink, 0x500, data, 9), -EINVAL);
    } else {
        assert_true(rc < 0);
        assert_int_equal(sink.fd, -1);
    }
    sink.ops->close(&sink);
    assert_int_equal(sink.fd, -1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(sends_every_frame_each_period, setup, teardown),
        cmocka_unit_test_setup_teardown(rolling_counter_wraps, setup, teardown),
        cmocka_unit_test_setup_teardown(groups_and_extended_ids, setup, teardown),
        cmocka_unit_test_setup_teardown(init_refuses_bad_configuration, setup, teardown),
        cmocka_unit_test_setup_teardown(full_queue_drops_the_rest_of_the_period, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(interface_down_is_tried_every_period, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(recovery_is_logged_once_with_the_loss, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(absent_interface_is_reopened_with_backoff, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(vanished_interface_closes_and_reopens, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(other_errors_reopen, setup, teardown),
        cmocka_unit_test_setup_teardown(bus_off_until_restarted, setup, teardown),
        cmocka_unit_test_setup_teardown(poll_reports_interface_down, setup, teardown),
        cmocka_unit_test_setup_teardown(no_snapshot_sends_not_sent_markers, setup, teardown),
        cmocka_unit_test_setup_teardown(runs_on_the_loop_and_closes_clean, setup, teardown),
        cmocka_unit_test(socketcan_sink_without_interface),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
