"""`babblegen verify`: a dataset re-simulated here reproduces to the bit, and a difference is named."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from babblegen.cli import main
from babblegen.provenance import machine


def test_a_dataset_made_here_reproduces_exactly(small_noveb_dataset: Path, capsys):
    assert main(["verify", str(small_noveb_dataset), "--episodes", "4"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    here = json.loads((small_noveb_dataset / "babblegen" / "run.json").read_text())["fingerprint"]["hash"]
    assert lines[0] == f"fingerprint: this machine computes like the one that made the dataset ({here})"
    assert lines[-1] == "4 of 4 sampled episodes reproduce exactly"


def test_verify_says_first_whether_this_machine_computes_like_the_one_that_made_the_dataset(
    small_noveb_dataset: Path, tmp_path, capsys
):
    copy = tmp_path / "copy"
    shutil.copytree(small_noveb_dataset, copy)
    info_path = copy / "babblegen" / "run.json"
    info = json.loads(info_path.read_text())
    here = info["fingerprint"]["hash"]
    info["fingerprint"]["hash"] = "0123456789abcdef"  # as if made on a machine of another kind
    info_path.write_text(json.dumps(info))
    assert main(["verify", str(copy), "--episodes", "1"]) == 0  # (it does compute like this one)
    first = capsys.readouterr().out.splitlines()[0]
    assert first == (
        f"fingerprint: this machine computes differently from the one that made the dataset ({here} here, "
        "0123456789abcdef recorded): expect episodes to differ"
    )
    del info["fingerprint"]  # made before fingerprints were recorded
    info_path.write_text(json.dumps(info))
    assert main(["verify", str(copy), "--episodes", "1"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first == f"fingerprint: none recorded (the dataset predates them); this machine's is {here}"


def test_a_recorded_value_that_differs_is_named_with_a_non_zero_exit(small_noveb_dataset: Path, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(small_noveb_dataset, copy)
    path = copy / "babblegen" / "attempts.jsonl"
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    executed = [r for r in rows if r["feasible"]]
    recorded = executed[0]["descriptor"]  # the first episode verify samples; "nothing changed" is all zeros
    executed[0]["descriptor"] = ("f" if set(recorded) == {"0"} else "0") * len(recorded)
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    info_path = copy / "babblegen" / "run.json"
    info = json.loads(info_path.read_text())
    info["machine"]["cpu"] = "Another CPU (family 25, model 1)"  # as if made elsewhere
    info_path.write_text(json.dumps(info))
    assert main(["verify", str(copy), "--episodes", "3"]) == 1
    lines = capsys.readouterr().out.strip().splitlines()
    line = next(x for x in lines if " sampled episodes " in x)
    assert line.startswith("0 of 3 sampled episodes reproduce exactly; then episode 0")
    assert "descriptor" in line
    # then what differs between where it was made and here: the CPU alone
    expected = f"machine.cpu: Another CPU (family 25, model 1) recorded, {machine()['cpu']} here"
    assert lines[lines.index(line) + 1 :] == [expected]


def test_a_changed_contact_impulse_is_named(small_noveb_dataset: Path, tmp_path, capsys):
    """The objects' per-frame contact impulses are compared too: one value changed in the parquet is found."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    copy = tmp_path / "copy"
    shutil.copytree(small_noveb_dataset, copy)
    (path,) = sorted((copy / "data").rglob("*.parquet"))[:1]
    table = pq.read_table(path)
    column = "observation.object_contacts"
    values = table[column].to_pylist()
    episodes = table["episode_index"].to_pylist()
    row = episodes.index(0) + 3  # episode 0 (the first verify samples), frame 3
    values[row] = [v + 0.5 for v in values[row]]
    table = table.set_column(table.column_names.index(column), column, pa.array(values, type=table[column].type))
    pq.write_table(table, path)
    assert main(["verify", str(copy), "--episodes", "3"]) == 1
    line = next(x for x in capsys.readouterr().out.splitlines() if " sampled episodes " in x)
    assert line.startswith("0 of 3 sampled episodes reproduce exactly; then episode 0")
    assert f"{column} differs from frame 3 on (by up to 0.5)" in line


def test_verify_refuses_what_is_not_a_dataset(tmp_path, capsys):
    assert main(["verify", str(tmp_path)]) == 2
    assert "is not a babblegen dataset" in capsys.readouterr().err
