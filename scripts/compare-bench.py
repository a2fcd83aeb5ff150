#!/usr/bin/python3
"""Compares two `arref bench` output folders run for run: the same cells and seeds (the same
command on two trees, or with one setting changed), matched by their labels.

    python3 scripts/compare-bench.py BEFORE_DIR AFTER_DIR [--list 40]

For runs.csv (scenes, robustness, ...): per experiment and method, and per robot and mesher in
the robustness experiment, the runs within ADD 10 and 20 mm, said OK, wrong OK (said OK more
than 20 mm off, or in a cell without the robot), the median ADD and how many runs kept their ADD
to the micrometre; then every run whose outcome changed (crossed 10 or 20 mm, or its status).
For auto_runs.csv (seedless rooms): rooms whose primary arm lies within 10 and 20 mm, 2-arm rooms
with both arms found, wrong OK, rooms without the arm said FAILED, the median time.

Counts are what the bench's tables count; this only puts two runs of it side by side, so that a
change is judged run for run and not by two totals alone (docs/robustness.md). Exit status 2 when
a folder has neither file or the two folders hold different runs of an experiment."""

import argparse
import csv
import math
import os
import statistics
import sys

SUCCESS_MM, WRONG_MM = 10.0, 20.0


class CompareError(Exception):
    pass


def read_rows(folder, name):
    path = os.path.join(folder, name)
    if not os.path.exists(path):
        return None
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def add_mm(row, column="add_mm"):
    """The run's ADD in mm; a run that failed with an error has none (infinite: never a success)."""
    try:
        value = float(row.get(column, "") or "nan")
    except ValueError:
        value = math.nan
    return math.inf if math.isnan(value) else value


def run_key(row):
    """A run's labels: every column before `ok` (experiment, method, cell, seed, ...)."""
    keys = []
    for column in row:
        if column == "ok":
            break
        keys.append(row[column])
    return tuple(keys)


def group_of(row):
    group = [row["experiment"], row["method"], row.get("size", "")]
    if row["experiment"] == "robustness":  # params: "robot mesher family seeds"
        group += row["params"].split()[:2]
    return tuple(group)


def wrong_ok(row):
    return row.get("status") == "OK" and (add_mm(row) > WRONG_MM or row.get("scene") == "empty")


def summarise(rows):
    adds = [add_mm(r) for r in rows]
    finite = [a for a in adds if math.isfinite(a)]
    return {"runs": len(rows), "10mm": sum(a <= SUCCESS_MM for a in adds), "20mm": sum(a <= WRONG_MM for a in adds),
            "ok": sum(r.get("status") == "OK" for r in rows), "wrong_ok": sum(wrong_ok(r) for r in rows),
            "median": statistics.median(finite) if finite else math.nan}


def room_key(row):
    return (row["method"], row["robot"], row["mesher"], row["arms"], row.get("other", ""), row["room"])


def pair_runs(before, after, name, key=run_key):
    """The two folders' runs (or rooms), matched by their labels: (before, after) pairs."""
    b = {key(r): r for r in before}
    a = {key(r): r for r in after}
    if len(b) != len(before) or len(a) != len(after):
        raise CompareError(f"{name}: two runs share the same labels; these are not one bench's runs")
    if b.keys() != a.keys():
        only_b, only_a = len(b.keys() - a.keys()), len(a.keys() - b.keys())
        raise CompareError(f"{name}: the folders hold different runs ({only_b} only before, {only_a} only after): "
                           "compare two runs of the same bench command")
    return [(b[k], a[k]) for k in b]


def changed(before, after, column="add_mm"):
    x, y = add_mm(before, column), add_mm(after, column)
    return (x <= SUCCESS_MM) != (y <= SUCCESS_MM) or (x <= WRONG_MM) != (y <= WRONG_MM) or \
        before.get("status") != after.get("status")


def fmt_number(value):
    return "-" if not math.isfinite(value) else f"{value:.2f}"


def listing(items, listed, line_of):
    """The first `listed` items, a line each, and how many more there are."""
    lines = [line_of(item) for item in items[:listed]]
    if len(items) > listed:
        lines.append(f"  ... and {len(items) - listed} more (--list)")
    return lines


def compare_runs(before, after, listed):
    pairs = pair_runs(before, after, "runs.csv")
    groups = {}
    for b, a in pairs:
        groups.setdefault(group_of(b), []).append((b, a))
    lines = ["runs.csv: group | runs | within 10 mm | within 20 mm | said OK | wrong OK | median ADD mm | same ADD"]
    for group, members in sorted(groups.items()) + [(("all",), pairs)]:
        sb, sa = summarise([b for b, _ in members]), summarise([a for _, a in members])
        same = sum(b.get("add_mm") == a.get("add_mm") for b, a in members)
        lines.append(" ".join(filter(None, group)) + f" | {sb['runs']} | {sb['10mm']} -> {sa['10mm']} | "
                     f"{sb['20mm']} -> {sa['20mm']} | {sb['ok']} -> {sa['ok']} | {sb['wrong_ok']} -> {sa['wrong_ok']} | "
                     f"{fmt_number(sb['median'])} -> {fmt_number(sa['median'])} | {same}")
    moved = [(b, a) for b, a in pairs if changed(b, a)]
    lines.append(f"runs whose outcome changed: {len(moved)} of {len(pairs)}")
    return lines + listing(moved, listed, lambda pair: (
        f"  {' '.join(v for v in run_key(pair[0]) if v)}: {fmt_number(add_mm(pair[0]))} mm {pair[0].get('status', '')}"
        f" -> {fmt_number(add_mm(pair[1]))} mm {pair[1].get('status', '')}"))


def room_counts(rows):
    arm = [r for r in rows if int(r["arms"]) > 0]
    two = [r for r in rows if int(r["arms"]) == 2]
    empty = [r for r in rows if int(r["arms"]) == 0]
    times = [float(r["ms"]) for r in rows if r.get("ms") not in (None, "", "nan")]
    return {"rooms": len(arm), "10mm": sum(add_mm(r, "primary_add_mm") <= SUCCESS_MM for r in arm),
            "20mm": sum(add_mm(r, "primary_add_mm") <= WRONG_MM for r in arm),
            "both": sum(int(r["arms_found"]) >= 2 for r in two), "two": len(two),
            "wrong_ok": sum(int(r["wrong_ok"]) for r in rows),
            "failed": sum(r["status"] == "FAILED" for r in empty), "empty": len(empty),
            "ms": statistics.median(times) if times else math.nan}


def compare_rooms(before, after, listed):
    pairs = pair_runs(before, after, "auto_runs.csv", room_key)
    lines = ["auto_runs.csv: method | arm within 10 mm | within 20 mm | both arms found | wrong OK | empty FAILED | ms median"]
    for method in sorted({b["method"] for b, _ in pairs}):
        cb = room_counts([b for b, _ in pairs if b["method"] == method])
        ca = room_counts([a for b, a in pairs if b["method"] == method])
        lines.append(f"{method} | {cb['10mm']} -> {ca['10mm']} of {cb['rooms']} | {cb['20mm']} -> {ca['20mm']} | "
                     f"{cb['both']} -> {ca['both']} of {cb['two']} | {cb['wrong_ok']} -> {ca['wrong_ok']} | "
                     f"{cb['failed']} -> {ca['failed']} of {cb['empty']} | {fmt_number(cb['ms'])} -> {fmt_number(ca['ms'])}")
    moved = [(b, a) for b, a in pairs if b["arms_found"] != a["arms_found"] or changed(b, a, "primary_add_mm")]
    lines.append(f"rooms whose outcome changed: {len(moved)} of {len(pairs)}")

    def line_of(pair):
        method, robot, mesher, arms, other, room = room_key(pair[0])
        beside = f" beside {other}" if other else ""
        side = lambda r: f"{fmt_number(add_mm(r, 'primary_add_mm'))} mm {r['status']}, {r['arms_found']} found"
        return f"  {method} {robot} {mesher}, {arms} arm(s){beside}, room {room}: {side(pair[0])} -> {side(pair[1])}"
    return lines + listing(moved, listed, line_of)


def compare(before_dir, after_dir, listed=40):
    for folder in (before_dir, after_dir):
        if not os.path.isdir(folder):
            raise CompareError(f"no such folder: {folder}")
    lines = []
    found = False
    for name, compare_fn in (("runs.csv", compare_runs), ("auto_runs.csv", compare_rooms)):
        before, after = read_rows(before_dir, name), read_rows(after_dir, name)
        if not before and not after:  # absent, or only a header (the experiment did not run)
            continue
        if not before or not after:
            missing = before_dir if not before else after_dir
            raise CompareError(f"{name} has runs in one folder only (none in {missing})")
        found = True
        lines += compare_fn(before, after, listed)
    if not found:
        raise CompareError(f"neither {before_dir} nor {after_dir} holds runs.csv or auto_runs.csv of `arref bench --out`")
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", help="arref bench --out folder of the first run")
    parser.add_argument("after", help="arref bench --out folder of the second run, same command")
    parser.add_argument("--list", type=int, default=40, help="list at most this many changed runs")
    args = parser.parse_args(argv)
    try:
        print("\n".join(compare(args.before, args.after, args.list)))
    except KeyError as e:
        print(f"compare-bench: a bench CSV lacks the column {e}: is it from another version of arref bench?",
              file=sys.stderr)
        return 2
    except (CompareError, ValueError) as e:
        print(f"compare-bench: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
