#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The layout shows the layers, and the docs hold together.

The layers come from the table in docs/architecture.md (layer, folder,
role), so the page and the check cannot disagree. Checked here:
- every folder of src/ has a layer, every header sits beside its source;
- an #include "x.h" points to the file's own folder or to a lower layer;
- no include circle between two modules (x.c and x.h are module x);
- only src/gateway/ includes gateway.h;
- every relative link in README.md and docs/*.md, and every heading it
  names (#anchor), exists; every docs/ path the man pages, the
  configuration and the sources name exists;
- every `make TARGET` the docs name is a target of the Makefile;
- README.md is an entrance: at most 300 lines, every page of docs/ one
  link away, and every section the README had before the pages were split
  out is a heading of a page it links to.
"""
import glob
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import check, run  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

ARCHITECTURE = os.path.join(ROOT, "docs", "architecture.md")
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def read(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


def layers():
    """{folder: layer} from the table in docs/architecture.md."""
    table = {}
    for line in read(ARCHITECTURE).splitlines():
        m = re.match(r"^\|\s*(\d+)\s*\|\s*`src/([a-z_]+)/`\s*\|", line)
        if m:
            table[m.group(2)] = int(m.group(1))
    return table


def sources():
    return sorted(glob.glob(os.path.join(ROOT, "src", "*", "*.[ch]")))


def folder_of(path):
    return os.path.basename(os.path.dirname(path))


def headers():
    """{header name: path} of every header under src/."""
    found = {}
    for path in glob.glob(os.path.join(ROOT, "src", "*", "*.h")):
        name = os.path.basename(path)
        check(name not in found, "%s is in two folders: %s and %s" % (name, found.get(name), path))
        found[name] = path
    return found


def includes(path):
    """[(line number, header name)] of the quoted includes of a file."""
    text = read(path)
    return [(text.count("\n", 0, m.start()) + 1, m.group(1)) for m in INCLUDE.finditer(text)]


def rel(path):
    return os.path.relpath(path, ROOT)


def test_every_folder_has_a_layer_and_headers_sit_beside_sources():
    table = layers()
    check(len(table) >= 5, "docs/architecture.md has no layer table: %s" % table)
    folders = {os.path.basename(d.rstrip("/")) for d in glob.glob(os.path.join(ROOT, "src", "*/"))}
    check(folders == set(table), "src/ has %s, the layer table %s" % (sorted(folders), sorted(table)))
    check(min(table.values()) == 0 and [f for f, n in table.items() if n == 0] == ["base"],
          "the bottom layer must be src/base alone: %s" % table)
    check(not os.path.exists(os.path.join(ROOT, "include")), "include/ still exists")
    for h in glob.glob(os.path.join(ROOT, "src", "*", "*.h")):
        c = h[:-2] + ".c"
        tables = glob.glob(h[:-2] + "_*.c")
        check(os.path.exists(c) or tables, "%s has no source beside it" % rel(h))


def test_includes_point_only_down():
    table = layers()
    where = headers()
    wrong = []
    for path in sources():
        mine = folder_of(path)
        for line, name in includes(path):
            if name.endswith(".c"):
                wrong.append("%s:%d includes a source file %s" % (rel(path), line, name))
                continue
            target = where.get(name)
            if target is None:
                continue  # a generated or system header in quotes
            theirs = folder_of(target)
            if theirs != mine and table[theirs] >= table[mine]:
                wrong.append("%s:%d includes %s (layer %d %s/ from layer %d %s/)" %
                             (rel(path), line, name, table[theirs], theirs, table[mine], mine))
    check(not wrong, "includes that do not point down:\n  " + "\n  ".join(wrong))


def module_graph():
    where = headers()
    graph = {}
    for path in sources():
        me = os.path.splitext(os.path.basename(path))[0]
        graph.setdefault(me, set())
        for _, name in includes(path):
            if name in where:
                other = os.path.splitext(name)[0]
                if other != me:
                    graph[me].add(other)
    return graph


def circles(graph):
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_circle_detection_finds_a_circle():
    """The check itself: a made-up circle of three modules is found."""
    check(circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]],
          "a circle of three was not found")
    check(circles({"a": {"b"}, "b": set()}) == [], "a line was taken for a circle")


def test_no_include_circle():
    found = circles(module_graph())
    check(not found, "include circles between modules: %s" % found)


def test_only_the_wiring_includes_gateway_h():
    outside = []
    for top in ("src", "sim"):
        for path in glob.glob(os.path.join(ROOT, top, "**", "*.[ch]"), recursive=True):
            if any(name == "gateway.h" for _, name in includes(path)) and \
                    not rel(path).startswith("src/gateway/"):
                outside.append(rel(path))
    check(not outside, "gateway.h included outside src/gateway/: %s" % outside)


def slug(heading):
    """A heading's anchor as GitHub makes it."""
    text = re.sub(r"`|\*\*|\*", "", heading.strip().lower())
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path):
    found, seen = set(), {}
    in_code = False
    for line in read(path).splitlines():
        if line.startswith("```"):
            in_code = not in_code
        if in_code or not line.startswith("#"):
            continue
        base = slug(line.lstrip("#"))
        n = seen.get(base, 0)
        seen[base] = n + 1
        found.add(base if n == 0 else "%s-%d" % (base, n))
    return found


def markdown_files():
    return [os.path.join(ROOT, "README.md")] + sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))


def links(path):
    text = read(path)
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    return re.findall(r"\]\(([^)\s]+)\)", text)


def test_every_docs_link_resolves():
    broken = []
    for path in markdown_files():
        for url in links(path):
            if re.match(r"^[a-z]+:", url):
                continue  # http:, mailto:, file:
            target, _, anchor = url.partition("#")
            full = os.path.normpath(os.path.join(os.path.dirname(path), target)) if target else path
            if not os.path.exists(full):
                broken.append("%s: %s (no such file)" % (rel(path), url))
            elif anchor and full.endswith(".md") and anchor not in anchors(full):
                broken.append("%s: %s (no such heading)" % (rel(path), url))
    check(not broken, "broken links:\n  " + "\n  ".join(broken))


def test_every_docs_path_named_elsewhere_exists():
    """The man pages, the configuration, the units, the Makefile and the
    sources send readers to docs/ pages by name: each must exist."""
    missing = []
    places = ["Makefile", "config/jakagw.conf"] + glob.glob(os.path.join(ROOT, "man", "*.in")) + \
        glob.glob(os.path.join(ROOT, "systemd", "*.in")) + sources()
    for place in places:
        path = place if os.path.isabs(place) else os.path.join(ROOT, place)
        for name in set(re.findall(r"\bdocs/([\w.-]+\.(?:md|csv|dbc|yml|png))", read(path))):
            if not os.path.exists(os.path.join(ROOT, "docs", name)):
                missing.append("%s names docs/%s" % (rel(path), name))
    check(not missing, "\n  ".join(missing))


def make_targets():
    text = read(os.path.join(ROOT, "Makefile"))
    targets = set()
    for m in re.finditer(r"^([A-Za-z0-9_./%$() -]+?)\s*:(?!=)", text, re.M):
        targets.update(m.group(1).split())
    for m in re.finditer(r"^\.PHONY:(.*)$", text, re.M):
        targets.update(m.group(1).split())
    return targets


def test_every_make_target_the_docs_name_exists():
    targets = make_targets()
    check({"all", "demo", "test", "deps"} <= targets, "Makefile targets not read: %s" % targets)
    named = {}
    for path in markdown_files() + glob.glob(os.path.join(ROOT, "man", "*.in")):
        text = read(path)
        # `make X` in running text, and make X at the start of a line of a
        # code block.
        for m in re.finditer(r"(?:`|^\s*(?:\$ |sudo )?)make ([a-z][a-z0-9-]*)\b(?!=)", text, re.M):
            named.setdefault(m.group(1), rel(path))
    missing = ["make %s (%s)" % (t, where) for t, where in sorted(named.items())
               if t not in targets]
    check(named, "no make target found in the docs: the pattern is wrong")
    check(not missing, "the docs name make targets that do not exist: %s" % missing)


# The sections of the README before its topics moved to docs/ pages: each
# must stay one link away from the README, as a heading of a page it links.
FORMER_SECTIONS = [
    "Quick start", "What a PLC sees", "Commands",
    "The command link: nothing sent late, checked when idle",
    "Modbus/TCP Security (TLS, port 802)", "Modbus RTU on RS-485",
    "The network-exception policy", "Metrics, the status page and the audit trail", "Faults",
    "CAN mirror", "Configuration", "Running as a service", "ARM boards", "Architecture",
    "jakasim", "Tests", "The chaos soak", "Performance", "Layout", "Licence",
]


def headings(path):
    return {re.sub(r"^#+\s*", "", line).strip() for line in read(path).splitlines()
            if line.startswith("#")}


def test_readme_is_an_entrance():
    readme = os.path.join(ROOT, "README.md")
    count = read(readme).count("\n")
    check(count <= 300, "README.md has %d lines (at most 300)" % count)
    linked = {os.path.normpath(os.path.join(ROOT, u.partition("#")[0]))
              for u in links(readme) if u.endswith(".md") or ".md#" in u}
    pages = set(glob.glob(os.path.join(ROOT, "docs", "*.md")))
    unlinked = sorted(rel(p) for p in pages - linked)
    check(not unlinked, "docs pages the README does not link: %s" % unlinked)
    reachable = headings(readme)
    for page in linked:
        if os.path.exists(page):
            reachable |= headings(page)
    lost = [s for s in FORMER_SECTIONS if not any(h == s or h.startswith(s) for h in reachable)]
    check(not lost, "former README sections no longer one link away: %s" % lost)


def unrun_tests(text):
    """The test_* and case_* functions a suite defines but never names
    again: its run list (or its case table) would not run them."""
    names = re.findall(r"^def ((?:test|case)_\w+)\(", text, re.M)
    return [n for n in names if len(re.findall(r"\b%s\b" % n, text)) < 2]


def test_every_test_function_is_run():
    """A test written and left out of its suite's run list passes for ever
    without running: every test_*/case_* function of every suite is named
    somewhere besides its definition."""
    sample = "def test_a():\n    pass\n\n\ndef test_b():\n    pass\n\n\nrun([test_a])\n"
    check(unrun_tests(sample) == ["test_b"], "the finder misses test_b: %s" % unrun_tests(sample))
    unrun = {}
    for path in sorted(glob.glob(os.path.join(ROOT, "tests", "*", "test_*.py"))):
        with open(path) as f:
            left = unrun_tests(f.read())
        if left:
            unrun[os.path.relpath(path, ROOT)] = left
    check(not unrun, "defined but never run: %s" % unrun)


if __name__ == "__main__":
    run([test_every_folder_has_a_layer_and_headers_sit_beside_sources,
         test_includes_point_only_down, test_circle_detection_finds_a_circle,
         test_no_include_circle, test_only_the_wiring_includes_gateway_h,
         test_every_docs_link_resolves, test_every_docs_path_named_elsewhere_exists,
         test_every_make_target_the_docs_name_exists, test_readme_is_an_entrance,
         test_every_test_function_is_run])
