/* SPDX-License-Identifier: MIT */
/*
 * vendor_client.h - models of the Modbus TCP clients PLC vendors ship,
 * keeping a PLC program's register image in step with jakagw as that
 * vendor's client does, one request at a time, driven by the request list
 * of the shipped example (plc/examples/<vendor>/, turned into a request
 * file by tests/plc/test_plc.py).
 *
 * Request file, one line each ('#' starts a comment):
 *   vendor NAME                      codesys, siemens, twincat, rockwell
 *   delay MS                         between two requests (a ProSoft module's)
 *   writes first                     a writer's rule: the first block that
 *                                    changed, in list order, then the coils
 *                                    (the heartbeat first whenever it changed)
 *   reconnect keeps                  after a reconnect, what was written is
 *                                    taken as still there (no write again)
 *   request INSTANCE TABLE FIRST COUNT TRIGGER [heartbeat] [single]
 * TABLE ir, di, hr or co; TRIGGER "cyclic MS" (every MS ms), "change"
 * (when the image of the range differs from what was written last) or
 * "turn" (the example's own order: reads in turn, the writes as its rule
 * picks them); "single": a range of coils written one changed coil per
 * request; "heartbeat": the write that alternates with the others.
 * INSTANCE: the client instance (one TCP connection each).
 */
#ifndef VENDOR_CLIENT_H
#define VENDOR_CLIENT_H

#include <stdbool.h>
#include <stdint.h>

struct vc_image {
    uint8_t *co, *di;
    uint16_t *ir, *hr;
};

struct vc_stats {
    long requests, reads, writes, refused, failures;
    long heartbeat_writes, other_writes, coil_writes;
};

/* Reads the request file; returns 0 or -1 (and says why on stderr). */
int vc_load(const char *path, const char *host, int port);
/* The image the client keeps in step, from now on; every write is
 * considered unsent (the client writes what the image holds). */
void vc_bind(const struct vc_image *image);
/* Before the program: what arrived since the last scan goes into the
 * image (a client publishes its inputs at the start of a task cycle). */
void vc_publish_inputs(void);
/* After the program: the requests due this scan, as the vendor's client
 * sends them. 'now_us': monotonic. */
void vc_run_requests(long long now_us);
/* The level the client last wrote to coil 'address' (0 or 1; 0 as well
 * for what it takes as 0 after a connection was made), or -1 when none of
 * its requests writes that coil. */
int vc_coil_written(int address);
void vc_close(void);
const struct vc_stats *vc_stats(void);
const char *vc_vendor(void);

#endif
