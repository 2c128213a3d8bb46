/* SPDX-License-Identifier: MIT */
/*
 * can_sink.h - where the CAN mirror's frames go: a small table of function
 * pointers, so the mirror never branches on the transport and tests use a
 * fake. The one real sink is a SocketCAN raw socket.
 *
 * No operation blocks: a sink that cannot take a frame now says so.
 */
#ifndef JAKAGW_CAN_SINK_H
#define JAKAGW_CAN_SINK_H

#include <stdint.h>

/* Set in a frame id for a 29-bit (extended) identifier, as in linux/can.h. */
#define CAN_SINK_EXTENDED 0x80000000u

/* Events poll_events() reports, as a bit mask. */
enum {
    CAN_SINK_EVENT_BUS_OFF = 1,   /* the controller went bus-off */
    CAN_SINK_EVENT_RESTARTED = 2, /* the controller restarted after bus-off */
    CAN_SINK_EVENT_ERROR = 4,     /* any other controller error report */
};

struct can_sink;

struct can_sink_ops {
    /*
     * Opens the sink on network interface 'interface'. Returns 0, or a
     * negative errno: -ENODEV no such interface, -EAFNOSUPPORT or
     * -EPROTONOSUPPORT no CAN support in the kernel, other socket errors.
     */
    int (*open)(struct can_sink *sink, const char *interface);
    /*
     * Queues one classic frame (dlc 0..8) without blocking. Returns 0, or
     * -ENOBUFS / -EAGAIN when the transmit queue is full, -ENETDOWN when the
     * interface is down, -ENXIO / -ENODEV when it has vanished, or another
     * negative errno.
     */
    int (*send)(struct can_sink *sink, uint32_t id, const uint8_t *data, uint8_t dlc);
    /* Reads the controller's error reports so far, without blocking: a mask
       of CAN_SINK_EVENT_*, or a negative errno. */
    int (*poll_events)(struct can_sink *sink);
    /* Closes what open() opened; safe on a sink that is not open. */
    void (*close)(struct can_sink *sink);
};

struct can_sink {
    const struct can_sink_ops *ops;
    int fd;     /* the SocketCAN sink's socket, -1 when closed */
    void *user; /* for other sinks */
};

/* Makes 'sink' a SocketCAN raw socket sink, closed. */
void can_sink_socketcan_init(struct can_sink *sink);

#endif
