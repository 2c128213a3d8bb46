/* SPDX-License-Identifier: MIT */
/*
 * ip_allow.h - a list of client addresses (the [modbus] write_allow key),
 * parsed once and compared as addresses, never as text.
 *
 * Every address is kept as IPv6, an IPv4 address in its IPv4-mapped form
 * (::ffff:a.b.c.d), so that a client of a dual-stack listener (bind = ::),
 * which the kernel reports as ::ffff:127.0.0.1, matches "127.0.0.1", and
 * any spelling of an IPv6 address ("::1", "0:0::1") matches any other.
 */
#ifndef JAKAGW_IP_ALLOW_H
#define JAKAGW_IP_ALLOW_H

#include <netinet/in.h>
#include <stdbool.h>
#include <stddef.h>
#include <sys/socket.h>

#define IP_ALLOW_MAX 8

struct ip_allow {
    unsigned count; /* 0: the list is empty */
    struct in6_addr addrs[IP_ALLOW_MAX];
};

/*
 * Parses one literal IPv4 or IPv6 address into its IPv6 form. Returns 0,
 * or -EINVAL when 'text' is not an address (a host name, a prefix, a scope
 * suffix: none is accepted).
 */
int ip_addr_parse(const char *text, struct in6_addr *out);

/* The address of 'sa' (AF_INET or AF_INET6) in IPv6 form; -EAFNOSUPPORT. */
int ip_addr_from_sockaddr(const struct sockaddr *sa, struct in6_addr *out);

/*
 * Parses a list separated by commas and/or spaces ("" is an empty list).
 * Returns 0, or -EINVAL with the reason in 'why' (the first word that is
 * not an address, or more than IP_ALLOW_MAX of them); 'out' is then empty.
 */
int ip_allow_parse(const char *list, struct ip_allow *out, char *why, size_t why_size);

/* Is 'addr' in the list? (An empty list contains nothing.) */
bool ip_allow_contains(const struct ip_allow *allow, const struct in6_addr *addr);

#endif
