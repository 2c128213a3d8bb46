#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""Writes a man page to stdout from its template in man/ and what the
programs say about themselves, so that the page cannot drift from the code:

  OPTIONS        the option lines of '<program> --help'
  CONFIGURATION  the keys and defaults of 'jakagw --print-config-keys', each
                 with the comment above it in config/jakagw.conf and what a
                 reload does with it
  LIVE_KEYS, RESTART_KEYS   the keys a reload applies, and the others
  EXIT_STATUS    the 'Exit status:' line of 'jakagw --help'

Fails, naming it, on a key that config/jakagw.conf lacks or shows with
another default, or an option line it cannot read.

  scripts/gen-man.py BUILD_DIR jakagw.8|jakasim.1
"""
import os
import re
import shlex
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))


class GenError(Exception):
    pass


def run(argv):
    """A binary of the build, through the tests' runner prefix if one is set
    (JAKAGW_RUNNER: qemu-user for an ARM build)."""
    runner = shlex.split(os.environ.get("JAKAGW_RUNNER", ""))
    return subprocess.run(runner + argv, check=True, capture_output=True, text=True).stdout


def roff_text(text):
    """Plain text as a roff text line: backslashes escaped, no leading
    control character, and option names with real minus signs."""
    text = text.replace("\\", "\\e")
    text = re.sub(r"(?<![\w-])(--?)(?=[a-z])", lambda m: "\\-" * len(m.group(1)), text)
    if text.startswith((".", "'")):
        text = "\\&" + text
    return text


def roff_word(text):
    return text.replace("\\", "\\e").replace("-", "\\-")


OPTION = re.compile(r"^  (?:(-\w), |    )?(--[a-z][\w-]*)(?: ([A-Z]+(?::[A-Z]+)?))?\s{2,}(\S.*)$")
CONTINUATION = re.compile(r"^\s{20,}(\S.*)$")


def options_section(help_text):
    """The option lines of --help as .TP paragraphs; a line ending in ':'
    between them (jakasim's 'Faults:') starts a subsection."""
    out = []
    started = False
    for line in help_text.splitlines():
        m = OPTION.match(line)
        if m:
            short, long, arg, text = m.groups()
            head = ""
            if short:
                head = "\\fB%s\\fR, " % roff_word(short)
            head += "\\fB%s\\fR" % roff_word(long)
            if arg:
                head += " \\fI%s\\fR" % arg
            out += [".TP", head, roff_text(text)]
            started = True
        elif started and CONTINUATION.match(line):
            out.append(roff_text(CONTINUATION.match(line).group(1)))
        elif started and re.match(r"^[A-Z][\w ]*:$", line):
            out += [".SS %s" % line[:-1]]
        elif started and line.strip() == "":
            break
        elif started:
            raise GenError("cannot read this --help line: %r" % line)
    if not out:
        raise GenError("no options found in --help")
    return "\n".join(out)


def exit_status_section(help_text):
    m = re.search(r"^Exit status: (.*)\.$", help_text, re.M)
    if not m:
        raise GenError("no 'Exit status:' line in --help")
    out = []
    for item in m.group(1).split(", "):
        code, _, meaning = item.partition(" ")
        if not code.isdigit():
            raise GenError("cannot read the exit status %r" % item)
        out += [".TP", ".B %s" % code, roff_text(meaning[0].upper() + meaning[1:] + ".")]
    return "\n".join(out)


def conf_comments(path):
    """{(section, key): (default, [comment lines])} from config/jakagw.conf:
    the comment block right above each key, in the order of the file."""
    keys = {}
    section, comment = None, []
    with open(path) as f:
        for line in f:
            line = line.rstrip("\n")
            if line.startswith("["):
                section, comment = line.strip("[]"), []
            elif line.startswith(";"):
                comment.append(line[1:].strip())
            elif "=" in line and section:
                key, _, value = line.partition("=")
                keys[(section, key.strip())] = (value.strip(), comment)
                comment = []
    return keys


def config_sections(build):
    rows = [line.split("\t") for line in
            run([os.path.join(build, "jakagw"), "--print-config-keys"]).splitlines()]
    described = conf_comments(os.path.join(ROOT, "config", "jakagw.conf"))
    for section, key, default, _ in rows:
        if (section, key) not in described:
            raise GenError("config/jakagw.conf does not show [%s] %s" % (section, key))
        if described[(section, key)][0] != default:
            raise GenError("config/jakagw.conf shows [%s] %s = %s; the default is %s"
                           % (section, key, described[(section, key)][0], default))
    listed = {(r[0], r[1]) for r in rows}
    for section, key in described:
        if (section, key) not in listed:
            raise GenError("config/jakagw.conf shows [%s] %s, which is not a key" % (section, key))

    # A key without a comment of its own shares the one above it.
    groups = []
    for section, key, default, reload in rows:
        comment = described[(section, key)][1]
        if groups and not comment and groups[-1]["section"] == section:
            groups[-1]["keys"].append((key, default, reload))
        else:
            groups.append({"section": section, "keys": [(key, default, reload)],
                           "comment": comment})
    out = []
    section = None
    for g in groups:
        if g["section"] != section:
            section = g["section"]
            out.append(".SS [%s]" % section)
        out.append(".TP")
        out.append(", ".join("\\fB%s\\fR = %s" % (roff_word(k), roff_word(d) if d else "(empty)")
                             for k, d, _ in g["keys"]))
        text = " ".join(g["comment"])
        if text:
            out.append(roff_text(text))
        reloads = {r for _, _, r in g["keys"]}
        if reloads == {"live"}:
            out.append("Reload: takes effect.")
        elif reloads == {"restart"}:
            out.append("Reload: needs a restart.")
        else:
            raise GenError("keys described together differ on reload: %s" % g["keys"])
    live = [(s, k) for s, k, _, r in rows if r == "live"]
    restart = [(s, k) for s, k, _, r in rows if r == "restart"]
    return "\n".join(out), key_list(live), key_list(restart)


def key_list(keys):
    """[section] key, ... as one roff paragraph, a line per key."""
    return ",\n".join("[%s] \\fB%s\\fR" % (s, roff_word(k)) for s, k in keys)


def changelog_date():
    with open(os.path.join(ROOT, "debian", "changelog")) as f:
        for line in f:
            m = re.match(r"^ -- .*>  \w{3}, (\d{1,2}) (\w{3}) (\d{4}) ", line)
            if m:
                months = "Jan Feb Mar Apr May Jun Jul Aug Sep Oct Nov Dec".split()
                return "%s-%02d-%02d" % (m.group(3), months.index(m.group(2)) + 1,
                                         int(m.group(1)))
    raise GenError("no date in debian/changelog")


def main():
    if len(sys.argv) != 3 or sys.argv[2] not in ("jakagw.8", "jakasim.1"):
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    build, page = sys.argv[1], sys.argv[2]
    program = page.split(".")[0]
    help_text = run([os.path.join(build, program), "--help"])
    version = run([os.path.join(build, "jakagw"), "--version"]).split()[1]
    with open(os.path.join(ROOT, "man", page + ".in")) as f:
        text = f.read()
    fill = {"@VERSION@": version, "@DATE@": changelog_date(),
            "@OPTIONS@": options_section(help_text)}
    if program == "jakagw":
        fill["@CONFIGURATION@"], fill["@LIVE_KEYS@"], fill["@RESTART_KEYS@"] = \
            config_sections(build)
        fill["@EXIT_STATUS@"] = exit_status_section(help_text)
    for mark, value in fill.items():
        if mark not in text:
            raise GenError("man/%s.in has no %s" % (page, mark))
        text = text.replace(mark, value)
    left = re.findall(r"@[A-Z_]+@", text)
    if left:
        raise GenError("man/%s.in: nothing fills %s" % (page, ", ".join(left)))
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except (GenError, subprocess.CalledProcessError, OSError) as e:
        print("gen-man: %s" % e, file=sys.stderr)
        sys.exit(1)
