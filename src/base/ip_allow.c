/* SPDX-License-Identifier: MIT */
/* ip_allow.c - see ip_allow.h. */
#include "ip_allow.h"

#include <arpa/inet.h>
#include <errno.h>
#include <stdio.h>
#include <string.h>

static void map_ipv4(const struct in_addr *v4, struct in6_addr *out)
{
    memset(out, 0, sizeof(*out));
    out->s6_addr[10] = 0xff;
    out->s6_addr[11] = 0xff;
    memcpy(&out->s6_addr[12], v4, 4);
}

int ip_addr_parse(const char *text, struct in6_addr *out)
{
    struct in_addr v4;

    if (inet_pton(AF_INET, text, &v4) == 1) {
        map_ipv4(&v4, out);
        return 0;
    }
    if (inet_pton(AF_INET6, text, out) == 1)
        return 0; /* an IPv4-mapped spelling is already in this form */
    return -EINVAL;
}

int ip_addr_from_sockaddr(const struct sockaddr *sa, struct in6_addr *out)
{
    if (sa->sa_family == AF_INET) {
        map_ipv4(&((const struct sockaddr_in *)sa)->sin_addr, out);
        return 0;
    }
    if (sa->sa_family == AF_INET6) {
        *out = ((const struct sockaddr_in6 *)sa)->sin6_addr;
        return 0;
    }
    return -EAFNOSUPPORT;
}

int ip_allow_parse(const char *list, struct ip_allow *out, char *why, size_t why_size)
{
    char words[512];

    memset(out, 0, sizeof(*out));
    if (strlen(list) >= sizeof(words)) {
        snprintf(why, why_size, "longer than %zu characters", sizeof(words) - 1);
        return -EINVAL;
    }
    snprintf(words, sizeof(words), "%s", list);
    for (char *save = NULL, *w = strtok_r(words, ", \t", &save); w;
         w = strtok_r(NULL, ", \t", &save)) {
        if (out->count == IP_ALLOW_MAX) {
            snprintf(why, why_size, "more than %d addresses", IP_ALLOW_MAX);
            memset(out, 0, sizeof(*out));
            return -EINVAL;
        }
        if (ip_addr_parse(w, &out->addrs[out->count]) != 0) {
            snprintf(why, why_size, "'%.60s' is not an IP address", w);
            memset(out, 0, sizeof(*out));
            return -EINVAL;
        }
        out->count++;
    }
    return 0;
}

bool ip_allow_contains(const struct ip_allow *allow, const struct in6_addr *addr)
{
    for (unsigned i = 0; i < allow->count; i++)
        if (memcmp(&allow->addrs[i], addr, sizeof(*addr)) == 0)
            return true;
    return false;
}
