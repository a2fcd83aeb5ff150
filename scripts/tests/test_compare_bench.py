"""scripts/compare-bench.py on small bench folders written here, with the bench's own columns."""

import csv
import importlib.util
import os

import pytest

SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "compare-bench.py")
spec = importlib.util.spec_from_file_location("compare_bench", SCRIPT)
compare_bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(compare_bench)

RUN_COLUMNS = ["experiment", "method", "size", "params", "scene", "cell", "seed", "perturbation", "seed_yaw_deg",
               "offset_x", "offset_y", "offset_z", "ok", "status", "rms_mm", "add_mm"]
ROOM_COLUMNS = ["method", "robot", "mesher", "arms", "other", "room", "status", "primary_add_mm", "arms_found",
                "wrong_ok", "ms"]


def run(cell, add, status="OK", scene="default", params="abb own user seeds"):
    return {"experiment": "robustness", "method": "arref-icp", "size": "small", "params": params, "scene": scene,
            "cell": str(cell), "seed": "0", "perturbation": "", "seed_yaw_deg": "0", "offset_x": "0", "offset_y": "0",
            "offset_z": "0", "ok": "1" if add is not None else "0", "status": status if add is not None else "",
            "rms_mm": "30", "add_mm": "" if add is None else str(add)}


def room(index, arms, add, status, found, wrong=0):
    return {"method": "arref-auto", "robot": "mh5", "mesher": "own", "arms": str(arms), "other": "", "room": str(index),
            "status": status, "primary_add_mm": "nan" if add is None else str(add), "arms_found": str(found),
            "wrong_ok": str(wrong), "ms": "300"}


def write(folder, name, columns, rows):
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, name), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    return str(folder)


def test_counts_each_side_and_lists_the_runs_that_crossed_a_bar(tmp_path):
    before = write(tmp_path / "a", "runs.csv", RUN_COLUMNS,
                   [run(0, 4.0), run(1, 12.0), run(2, 25.0), run(3, 3.0, scene="empty"), run(4, None)])
    after = write(tmp_path / "b", "runs.csv", RUN_COLUMNS,
                  [run(0, 4.0), run(1, 8.0), run(2, 15.0, "LOW_CONFIDENCE"), run(3, 3.0, scene="empty"), run(4, 6.0)])
    lines = compare_bench.compare(before, after)
    group = next(line for line in lines if line.startswith("robustness arref-icp small abb own"))
    # within 10 mm: 2 -> 4 (an error counts as a failure); within 20: 3 -> 5; said OK 4 -> 4;
    # wrong OK: 25 mm OK and the empty cell's OK before, the empty cell's only after; the median
    # over the runs with an ADD (8 of 3, 4, 12, 25 before).
    assert group == "robustness arref-icp small abb own | 5 | 2 -> 4 | 3 -> 5 | 4 -> 4 | 2 -> 1 | 8.00 -> 6.00 | 2"
    assert "runs whose outcome changed: 3 of 5" in lines
    assert any("12.00 mm OK -> 8.00 mm OK" in line for line in lines)
    assert any("25.00 mm OK -> 15.00 mm LOW_CONFIDENCE" in line for line in lines)
    assert any(": - mm  -> 6.00 mm OK" in line for line in lines)


def test_the_list_is_cut_where_asked(tmp_path):
    before = write(tmp_path / "a", "runs.csv", RUN_COLUMNS, [run(i, 12.0) for i in range(5)])
    after = write(tmp_path / "b", "runs.csv", RUN_COLUMNS, [run(i, 8.0) for i in range(5)])
    lines = compare_bench.compare(before, after, listed=2)
    assert sum(line.startswith("  robustness") for line in lines) == 2
    assert lines[-1] == "  ... and 3 more (--list)"


def test_rooms_count_arms_found_and_empty_rooms_failed(tmp_path):
    before = write(tmp_path / "a", "auto_runs.csv", ROOM_COLUMNS,
                   [room(0, 1, 12.0, "OK", 0), room(1, 2, 6.0, "OK", 2), room(2, 0, None, "LOW_CONFIDENCE", 0)])
    after = write(tmp_path / "b", "auto_runs.csv", ROOM_COLUMNS,
                  [room(0, 1, 7.0, "OK", 1), room(1, 2, 6.0, "OK", 1), room(2, 0, None, "FAILED", 0)])
    lines = compare_bench.compare(before, after)
    assert lines[1] == "arref-auto | 1 -> 2 of 2 | 2 -> 2 | 1 -> 0 of 1 | 0 -> 0 | 0 -> 1 of 1 | 300.00 -> 300.00"
    assert "rooms whose outcome changed: 3 of 3" in lines


def test_different_runs_are_refused(tmp_path):
    before = write(tmp_path / "a", "runs.csv", RUN_COLUMNS, [run(0, 4.0), run(1, 5.0)])
    after = write(tmp_path / "b", "runs.csv", RUN_COLUMNS, [run(0, 4.0), run(2, 5.0)])
    with pytest.raises(compare_bench.CompareError, match="different runs"):
        compare_bench.compare(before, after)
    assert compare_bench.main([before, after]) == 2


def test_folders_without_bench_output_are_refused(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(compare_bench.CompareError, match="neither"):
        compare_bench.compare(str(empty), str(empty))
    with pytest.raises(compare_bench.CompareError, match="no such folder"):
        compare_bench.compare(str(tmp_path / "missing"), str(empty))


def test_a_csv_from_another_bench_is_refused_by_name(tmp_path, capsys):
    columns = [c for c in ROOM_COLUMNS if c != "arms_found"]
    rows = [{c: v for c, v in room(0, 1, 5.0, "OK", 1).items() if c != "arms_found"}]
    before = write(tmp_path / "a", "auto_runs.csv", columns, rows)
    after = write(tmp_path / "b", "auto_runs.csv", columns, rows)
    assert compare_bench.main([before, after]) == 2
    assert "lacks the column 'arms_found'" in capsys.readouterr().err
