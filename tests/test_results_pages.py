"""Results pages show what their committed results files hold: every table of a generated page is marked
with the results.json files `mop benchmark` wrote, or the report `mop reproduce` or a script wrote, and
equals the table rendered or copied from them (mop.benchmarks.pages); the renderer writes those files'
numbers in the field's units."""

import json
from pathlib import Path

import pytest

from mop.benchmarks.pages import expected, render, rewrite, tables

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"
# the pages whose every table comes from results files
GENERATED = ["benchmarks.md", "paper.md", "families.md", "class-models.md"]


@pytest.mark.parametrize("page", GENERATED)
def test_every_table_of_the_page_is_its_results_files(page):
    found = tables(RESULTS / page)
    assert found, f"{page} has no table"
    for marker, bench, files, table in found:
        assert bench, f"{page}: the table after line {marker + 1} names no results files"
        for f in files:
            if f.suffix == ".json":
                provenance = json.loads(f.read_text())["provenance"]
                assert provenance["commit"] != "unknown" and provenance["command"].startswith("mop benchmark")
        assert table == expected(bench, files), f"{page}: the table after line {marker + 1} is not its files'"


def test_a_table_is_rendered_from_its_files_in_the_fields_units(tmp_path):
    result = {
        "silverbox": {
            "test_multisine": {"mop": {"rmse": 0.0009, "n": 50}, "arx": {"rmse": 0.00713, "n": 50}},
            "test_arrow_full": {"mop": {"rmse": float("inf"), "n": 50}, "arx": {"rmse": 0.01493, "n": 50}},
        },
        "provenance": {"command": "mop benchmark silverbox --seed 2", "commit": "abc"},
    }
    path = tmp_path / "r.json"
    path.write_text(json.dumps(result))  # inf as Infinity, as mop's write_json writes it
    assert render("silverbox", [path]) == [
        "| predictor (mV) | test_multisine (n = 50) | test_arrow_full (n = 50) |",
        "|---|---|---|",
        "| mop, seed 2 | 0.9 | diverged |",
        "| arx | 7.13 | 14.93 |",
        "| best published baseline (Champneys et al. 2024) | 1.5 (LSTM, GRU) | 2.4 (OLSTM) |",
        "| state of the art (black box) | 0.26 | 1.41 |",
    ]
    page = tmp_path / "page.md"
    page.write_text("# x\n\n<!-- results-table: silverbox r.json -->\n| stale |\n|---|\n| 1 |\n\ntext\n")
    rewrite(page)
    ((_, bench, files, table),) = tables(page)
    assert table == render("silverbox", files) and page.read_text().endswith("\ntext\n")


def test_a_row_trained_with_keys_is_labelled_with_them(tmp_path):
    result = {
        "silverbox": {"test_multisine": {"mop": {"rmse": 0.0009, "n": 50}}},
        "provenance": {"command": "mop benchmark silverbox --seed 1 --train train.simulate_after=10 --quiet"},
    }
    path = tmp_path / "r.json"
    path.write_text(json.dumps(result))
    assert render("silverbox", [path])[2] == "| mop (train.simulate_after=10), seed 1 | 0.9 |"
    result["provenance"]["command"] = (
        "mop benchmark silverbox --budget 30 --seed 1 --train a.b=1 --predictors lru"
    )
    result["silverbox"]["test_multisine"]["lru"] = {"rmse": 0.002, "n": 50}
    path.write_text(json.dumps(result))
    assert render("silverbox", [path])[2:4] == [
        "| mop (a.b=1), budget 30 min, seed 1 | 0.9 |",
        "| lru, budget 30 min, seed 1 | 2 |",
    ]
    # the candidates a records run's check did not keep, scored beside it (mop benchmark's mop:PART)
    result["provenance"]["command"] = "mop benchmark silverbox --seed 2"
    result["silverbox"]["test_multisine"] = {
        "mop": {"rmse": 0.0009, "n": 50},
        "mop:network": {"rmse": 0.0012, "n": 50},
        "mop:feature": {"rmse": 0.0011, "n": 50},
    }
    path.write_text(json.dumps(result))
    assert render("silverbox", [path])[2:5] == [
        "| mop, seed 2 | 0.9 |",
        "| mop, the network alone, seed 2 | 1.2 |",
        "| mop, its least-squares feature alone, seed 2 | 1.1 |",
    ]
    # and a fine-tune's (finetune:NAME:PART)
    result["silverbox"]["test_multisine"] = {
        "finetune:duffing-lru": {"rmse": 0.0008, "n": 50},
        "finetune:duffing-lru:feature": {"rmse": 0.0011, "n": 50},
    }
    path.write_text(json.dumps(result))
    assert render("silverbox", [path])[2:4] == [
        "| finetune:duffing-lru, seed 2 | 0.8 |",
        "| finetune:duffing-lru, its least-squares feature alone, seed 2 | 1.1 |",
    ]
    # a row another file gives already (the fitted ARX of every run) is shown once; a differing one twice
    result["silverbox"]["test_multisine"] = {"arx": {"rmse": 0.007, "n": 50}}
    path.write_text(json.dumps(result))
    other = tmp_path / "other.json"
    other.write_text(json.dumps(result))
    assert [row for row in render("silverbox", [path, other]) if row.startswith("| arx")] == ["| arx | 7 |"]
    result["silverbox"]["test_multisine"]["arx"]["rmse"] = 0.008
    other.write_text(json.dumps(result))
    assert len([row for row in render("silverbox", [path, other]) if row.startswith("| arx")]) == 2


def test_a_copied_table_is_the_files_kth_table(tmp_path):
    (tmp_path / "summary.md").write_text(
        "# s\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\ntext\n\n| c |\n|---|\n| 3 |\n"
    )
    page = tmp_path / "page.md"
    page.write_text("<!-- results-copy: summary.md#2 -->\n| c |\n|---|\n| 4 |\n")
    ((_, kind, files, table),) = tables(page)
    assert kind == "copy:2" and table != expected(kind, files)  # a number the file does not give
    rewrite(page)
    assert tables(page)[0][3] == ["| c |", "|---|", "| 3 |"]
