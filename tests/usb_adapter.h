/* SPDX-License-Identifier: MIT */
/*
 * usb_adapter.h - USB serial adapters as they hand received bytes to the
 * host, for the serial line's property tests (test_rtu_frame.c). A USB
 * adapter does not hand over each byte: it collects what it received in
 * a packet and sends the packet when it is full or when its latency timer
 * runs out, so a gap the host sees may be that timer, and one packet may
 * hold the tail of one frame and the head of the next.
 *
 * The table, with where each figure comes from:
 *   - FTDI FT232R/FT232H (Linux ftdi_sio): 64-byte bulk-in packets whose
 *     first 2 bytes are modem and line status, so 62 bytes of data each;
 *     a partial packet goes when the latency timer runs out, 16 ms by
 *     default, 1-255 ms (FTDI application note AN232B-04, "Data
 *     Throughput, Latency and Handshaking", sections 3.1-3.3; ftdi_sio
 *     sets 1 ms for ASYNC_LOW_LATENCY and shows the timer in sysfs as
 *     latency_timer).
 *   - WCH CH340/CH341 (Linux ch341): a 32-byte bulk-in endpoint
 *     (the driver's bulk_in_size follows the endpoint's wMaxPacketSize).
 *     WCH's datasheet gives no receive timeout and the driver exposes
 *     none: modelled at 16 ms, the bound [rtu] delivery_ms assumes.
 *   - Silicon Labs CP2102 (Linux cp210x): a 64-byte bulk-in endpoint
 *     (CP2102 datasheet, "USB function controller": 64-byte endpoints).
 *     Its receive timeout is not in the datasheet either: modelled at
 *     16 ms, as for the CH340.
 * Every packet reaches the host at the next USB frame (1 ms, full speed).
 */
#ifndef JAKAGW_TESTS_USB_ADAPTER_H
#define JAKAGW_TESTS_USB_ADAPTER_H

#include <stddef.h>
#include <stdint.h>

struct usb_adapter {
    const char *name;
    unsigned payload;    /* received bytes per packet */
    unsigned latency_ms; /* a partial packet goes when this timer runs out */
};

static const struct usb_adapter usb_adapters[] = {
    {"FTDI, latency timer 16 ms", 62, 16},
    {"FTDI, latency timer 1 ms", 62, 1},
    {"CH340", 32, 16},
    {"CP2102", 64, 16},
};

#define USB_FRAME_NS 1000000ull

/* An adapter's receive side: the bytes of the packet it is filling. */
struct usb_port {
    const struct usb_adapter *adapter;
    uint64_t phase_ns; /* the latency timer runs out at phase + k * latency */
    uint8_t held[64];
    size_t held_n;
    uint64_t held_since_ns; /* when the first byte held came */
};

/* When the timer next runs out at or after 't'. */
static uint64_t usb_timer_after(const struct usb_port *p, uint64_t t)
{
    uint64_t period = (uint64_t)p->adapter->latency_ms * 1000000ull;
    if (t <= p->phase_ns)
        return p->phase_ns;
    return p->phase_ns + (t - p->phase_ns + period - 1) / period * period;
}

#endif
