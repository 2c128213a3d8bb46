/* SPDX-License-Identifier: MIT */
#include "json_member.h"

#include <string.h>

const cJSON *json_member_last(const cJSON *obj, const char *key)
{
    const cJSON *found = NULL;
    if (!cJSON_IsObject(obj))
        return NULL;
    for (const cJSON *m = obj->child; m; m = m->next)
        if (m->string && strcmp(m->string, key) == 0)
            found = m;
    return found;
}
