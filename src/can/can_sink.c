/* SPDX-License-Identifier: MIT */
/* can_sink.c - the SocketCAN sink (can_sink.h). */
#include "can_sink.h"

#include <errno.h>
#include <net/if.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>

/* Error reports read per poll: enough for any burst between two periods
   without letting a storm of reports hold the loop. */
#define MAX_REPORTS_PER_POLL 64

static void socketcan_close(struct can_sink *sink)
{
    if (sink->fd >= 0)
        close(sink->fd);
    sink->fd = -1;
}

/* The canonical open sequence: socket, interface index, bind. */
static int socketcan_open(struct can_sink *sink, const char *interface)
{
    /* Receive no data frames, only the controller's error reports. */
    const can_err_mask_t errors = CAN_ERR_BUSOFF | CAN_ERR_RESTARTED | CAN_ERR_CRTL;
    struct sockaddr_can addr;
    unsigned index;
    int fd, rc;

    socketcan_close(sink);
    index = if_nametoindex(interface);
    if (index == 0)
        return errno == ENXIO ? -ENODEV : -errno;
    fd = socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
    if (fd < 0)
        return -errno;
    if (setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, NULL, 0) < 0 ||
        setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &errors, sizeof(errors)) < 0) {
        rc = -errno;
        close(fd);
        return rc;
    }
    memset(&addr, 0, sizeof(addr));
    addr.can_family = AF_CAN;
    addr.can_ifindex = (int)index;
    if (bind(fd, (struct sockaddr *)&addr, sizeof(addr)) < 0) {
        rc = -errno;
        close(fd);
        return rc;
    }
    sink->fd = fd;
    return 0;
}

static int socketcan_send(struct can_sink *sink, uint32_t id, const uint8_t *data,
                          uint8_t dlc)
{
    struct can_frame frame;
    ssize_t n;

    if (sink->fd < 0)
        return -EBADF;
    if (dlc > CAN_MAX_DLEN)
        return -EINVAL;
    memset(&frame, 0, sizeof(frame));
    frame.can_id = id & CAN_SINK_EXTENDED ? (id & CAN_EFF_MASK) | CAN_EFF_FLAG
                                          : id & CAN_SFF_MASK;
    frame.len = dlc;
    memcpy(frame.data, data, dlc);
    n = write(sink->fd, &frame, sizeof(frame));
    if (n < 0)
        return errno == EWOULDBLOCK ? -EAGAIN : -errno;
    return n == (ssize_t)sizeof(frame) ? 0 : -EIO;
}

static int socketcan_poll_events(struct can_sink *sink)
{
    struct can_frame frame;
    int events = 0;

    if (sink->fd < 0)
        return -EBADF;
    for (int i = 0; i < MAX_REPORTS_PER_POLL; i++) {
        ssize_t n = recv(sink->fd, &frame, sizeof(frame), MSG_DONTWAIT);
        if (n < 0) {
            if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)
                break;
            return -errno;
        }
        if (n != (ssize_t)sizeof(frame) || !(frame.can_id & CAN_ERR_FLAG))
            continue;
        if (frame.can_id & CAN_ERR_BUSOFF)
            events |= CAN_SINK_EVENT_BUS_OFF;
        if (frame.can_id & CAN_ERR_RESTARTED)
            events |= CAN_SINK_EVENT_RESTARTED;
        if (frame.can_id & ~(CAN_ERR_FLAG | CAN_ERR_BUSOFF | CAN_ERR_RESTARTED))
            events |= CAN_SINK_EVENT_ERROR;
    }
    return events;
}

static const struct can_sink_ops socketcan_ops = {
    .open = socketcan_open,
    .send = socketcan_send,
    .poll_events = socketcan_poll_events,
    .close = socketcan_close,
};

void can_sink_socketcan_init(struct can_sink *sink)
{
    memset(sink, 0, sizeof(*sink));
    sink->ops = &socketcan_ops;
    sink->fd = -1;
}
