/* SPDX-License-Identifier: MIT */
/*
 * status_doc.h - jakasim's port-10000 document, in the real wire format:
 * "len" first and exact (the byte length of the whole object), Python
 * separators, fields and array lengths of a chosen controller version.
 */
#ifndef JAKASIM_STATUS_DOC_H
#define JAKASIM_STATUS_DOC_H

#include <stdbool.h>

#include "pyjson.h"
#include "robot.h"

struct sim_profile {
    const char *name;
    int dio;          /* din/dout length */
    int aio;          /* ain/aout length */
    int tio_ain;
    int monitor_top;  /* monitor_data entries (6 in the manual, 10 seen) */
    int monitor_joint;/* values per joint row (10 in the manual, 11 seen) */
    int torq_status;  /* torqsensor[1] entries */
    bool extio;
    bool extras;      /* instVel, joint_position, ... tio_rs_signals */
};

/* "manual" (protocol 2.0.4), "zu5s" (1.5.14), "full" (the richest seen). */
const struct sim_profile *sim_profile_find(const char *name);

/*
 * Writes one document into 'w' (reset first). 'pad' extra bytes of errmsg
 * make an oversize document for fault tests. Returns the document's length.
 */
size_t sim_status_document(struct pyjson *w, const struct sim_robot *r,
                           const struct sim_profile *p, size_t pad);

#endif
