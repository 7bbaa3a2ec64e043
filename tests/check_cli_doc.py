#!/usr/bin/python3
"""Checks docs/cli.md against the command line's own help, so the two cannot drift.

    /usr/bin/python3 tests/check_cli_doc.py BUILD/vdbrecon docs/cli.md

Reads `vdbrecon --help` and the help of every subcommand its usage lines name
("or:  vdbrecon fuse ...": `vdbrecon fuse --help`, `vdbrecon eval --help"), and parses each
option entry: the option names at the start of the entry ("  --voxel V", "  -o, --output PATH",
"  --min-depth D, --max-depth D"; an option introduced inside a description as "; --no-carve:")
and its default, the text of the last [...] in the entry's description (an entry without one
has no default, except "(default)" after the first of the choices a|b of its argument). The
help's groups ("splat options:") are the groups of cli.md.

cli.md's convention: one "## Group" heading per help group (the group's name without
"options"), and under it a table whose rows are

    | `--option ARG` | `default` | what it does |

the first cell naming the option(s) of one help entry, the second the help's default in one code
span, or "—" when the help states none. Where an entry names several options and its default
lists one value per option ("[0, none]"), a row may name one of them with its own value.
In a default, "…" stands for a value the help computes on the machine it runs on (the memory
budget).

Fails (exit status 1, listing every problem) when an option of the help is missing from cli.md,
when cli.md names an option (anywhere) that no help has, when an option sits under another
group than in the help, or when a default differs. Exit status 2 for usage errors.
"""
import re
import subprocess
import sys

NAME = re.compile(r"(?<![\w-])(--[a-z0-9][a-z0-9-]*|-[a-zA-Z])(?![\w-])")
LONG_NAME = re.compile(r"(?<![\w`-])--[a-z0-9][a-z0-9-]*(?![\w-])")
INLINE_OPTION = re.compile(r";\s*(--[a-z0-9][a-z0-9-]*):")
NONE = "—"


def norm(text):
    """Whitespace collapsed, so line breaks of the help do not matter."""
    return " ".join(text.split())


def run_help(binary, *args):
    try:
        out = subprocess.run([binary, *args, "--help"], capture_output=True, text=True,
                             timeout=60)
    except OSError as e:
        sys.exit("check_cli_doc: cannot run %s: %s" % (binary, e))
    if out.returncode != 0:
        sys.exit("check_cli_doc: '%s %s --help' exited with %d:\n%s"
                 % (binary, " ".join(args), out.returncode, out.stderr))
    return out.stdout


def parse_help(text):
    """[(group, [names], default or None)] in help order; the subcommands of the usage lines."""
    subcommands = re.findall(r"^\s*or:\s+\S+\s+([a-z]+)\b", text, re.M)
    entries = []
    group = None
    current = None  # [group, head, description lines]

    def close():
        if current is None:
            return
        grp, head, desc = current
        names = NAME.findall(head)
        description = norm(" ".join(desc))
        defaults = re.findall(r"\[([^\[\]]*)\]", description)
        default = norm(defaults[-1]) if defaults else None
        if default is None and "(default)" in description:
            choice = re.search(r"\s([a-z0-9_]+)\|", head)
            if choice:
                default = choice.group(1)
        entries.append((grp, names, default))
        for inline in INLINE_OPTION.findall(description):
            entries.append((grp, [inline], None))

    for line in text.splitlines():
        header = re.match(r"^(\S.*?) options:", line)
        if header:
            close()
            current = None
            group = norm(header.group(1)).lower()
            continue
        option = re.match(r"^  (-\S.*)$", line)
        if option:
            close()
            # The head ends at the first run of two or more spaces.
            parts = re.split(r"\s{2,}", option.group(1), maxsplit=1)
            current = [group, parts[0], [parts[1]] if len(parts) > 1 else []]
            continue
        if current is not None and re.match(r"^ {8,}\S", line):
            current[2].append(line.strip())
            continue
        close()
        current = None
    close()
    return entries, subcommands


def per_name(names, default):
    """{name: default}: one value per name where the default lists as many, else the same."""
    if default is not None and len(names) > 1:
        values = [v.strip() for v in default.split(",")]
        if len(values) == len(names):
            return dict(zip(names, values))
    return {n: default for n in names}


def split_row(line):
    """The cells of a Markdown table row (escaped pipes and pipes in code spans kept)."""
    cells, cell, code = [], "", False
    body = line.strip()
    if body.startswith("|"):
        body = body[1:]
    if body.endswith("|") and not body.endswith("\\|"):
        body = body[:-1]
    i = 0
    while i < len(body):
        c = body[i]
        if c == "\\" and i + 1 < len(body) and body[i + 1] == "|":
            cell += "|"
            i += 2
            continue
        if c == "`":
            code = not code
        if c == "|" and not code:
            cells.append(cell.strip())
            cell = ""
        else:
            cell += c
        i += 1
    cells.append(cell.strip())
    return cells


def parse_doc(path):
    """{name: (group, default cell, line number)}, every option name anywhere, problems."""
    rows, anywhere, problems = {}, {}, []
    group = None
    with open(path, encoding="utf-8") as f:
        lines = f.read().splitlines()
    in_code = False
    for number, line in enumerate(lines, 1):
        if line.startswith("```"):
            in_code = not in_code
        for name in LONG_NAME.findall(line.replace("`", " ")):
            anywhere.setdefault(name, number)
        if in_code:
            continue
        heading = re.match(r"^##\s+(.*?)\s*$", line)
        if heading:
            group = norm(heading.group(1)).lower()
            continue
        if not line.lstrip().startswith("|"):
            continue
        cells = split_row(line)
        if len(cells) < 3 or re.fullmatch(r":?-+:?", cells[0] or "-"):
            continue
        names = NAME.findall(cells[0].replace("`", " "))
        if not names:
            continue  # a header row
        cell = cells[1]
        if cell == NONE:
            default = None
        else:
            code = re.fullmatch(r"`([^`]*)`", cell)
            if not code:
                problems.append("%s:%d: the default of %s is neither one code span nor %s: %r"
                                % (path, number, ", ".join(names), NONE, cell))
                continue
            default = norm(code.group(1))
        for name, value in per_name(names, default).items():
            if name in rows:
                problems.append("%s:%d: %s has a second row (first on line %d)"
                                % (path, number, name, rows[name][2]))
            rows[name] = (group, value, number)
    return rows, anywhere, problems


def matches(doc_default, help_default):
    if doc_default is None or help_default is None:
        return doc_default == help_default
    pattern = ".+?".join(re.escape(part) for part in doc_default.split("…"))
    return re.fullmatch(pattern, help_default) is not None


def main(argv):
    if len(argv) != 3:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    binary, doc = argv[1], argv[2]
    text = run_help(binary)
    entries, subcommands = parse_help(text)
    for sub in subcommands:
        entries += parse_help(run_help(binary, sub))[0]

    wanted = {}  # name -> (group, default, source)
    problems = []
    for group, names, default in entries:
        for name, value in per_name(names, default).items():
            seen = wanted.get(name)
            if seen and (seen[0], seen[1]) != (group, value):
                problems.append("the helps disagree on %s: group %r default %r, and group %r "
                                "default %r" % (name, seen[0], seen[1], group, value))
            wanted.setdefault(name, (group, value))
    if not wanted:
        print("check_cli_doc: no option found in '%s --help'" % binary, file=sys.stderr)
        return 1

    rows, anywhere, doc_problems = parse_doc(doc)
    problems += doc_problems
    for name, (group, default) in sorted(wanted.items()):
        if name not in rows:
            problems.append("%s is in --help (%s options) but has no row in %s"
                            % (name, group, doc))
            continue
        doc_group, doc_default, line = rows[name]
        if doc_group != group:
            problems.append("%s:%d: %s is under '## %s', --help has it under '%s options'"
                            % (doc, line, name, doc_group, group))
        if not matches(doc_default, default):
            problems.append("%s:%d: %s: default %s in %s, %s in --help"
                            % (doc, line, name,
                               NONE if doc_default is None else "[%s]" % doc_default, doc,
                               "none" if default is None else "[%s]" % default))
    for name, line in sorted(anywhere.items(), key=lambda x: x[1]):
        if name not in wanted:
            problems.append("%s:%d: %s is not an option of vdbrecon (not in any --help)"
                            % (doc, line, name))
    for name in sorted(set(rows) - set(wanted)):
        if name.startswith("--"):
            continue  # reported above
        problems.append("%s:%d: %s is not an option of vdbrecon" % (doc, rows[name][2], name))

    if problems:
        print("check_cli_doc: %s does not match '%s --help' (%d problems):"
              % (doc, binary, len(problems)), file=sys.stderr)
        for p in problems:
            print("  " + p, file=sys.stderr)
        return 1
    print("check_cli_doc: %d options of %s (help groups: %s) documented in %s with their defaults"
          % (len(wanted), binary, ", ".join(sorted({g for g, _ in wanted.values()})), doc))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
