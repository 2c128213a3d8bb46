/* SPDX-License-Identifier: MIT */
/*
 * json_member.h - a member of a JSON object as the robot controller reads
 * it.
 *
 * The controller reads requests as Python's json.loads does: a member given
 * twice counts with its LAST value. cJSON's own lookup
 * (cJSON_GetObjectItemCaseSensitive) returns the first. Anything that must
 * agree with the robot on what a request says (the gateway's motion
 * tracker, the simulator) looks members up here.
 */
#ifndef JAKAGW_JSON_MEMBER_H
#define JAKAGW_JSON_MEMBER_H

#include <cJSON.h>

/* The last member of 'obj' named 'key' (case-sensitive); NULL when 'obj'
 * is not an object or has none. */
const cJSON *json_member_last(const cJSON *obj, const char *key);

#endif
