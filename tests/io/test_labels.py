"""Label text files, label merging with " - Copy", labels of .cara projects."""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from carapost.io.errors import CaraFileError
from carapost.io.labels import (
    merge_labels,
    read_label_file,
    read_labels_from_cara,
    write_label_file,
)

GUIDE_EXAMPLE = (
    "Mouth_L_Corner  \nMouth_R_Corner  \nChin_Center  \nChin_L_Pt1  \nChin_L_Pt2  \n"
    "Chin_R_Pt1  \nChin_R_Pt2  \nNose_Tip\n"
)


def test_one_label_per_line(tmp_path: Path) -> None:
    path = tmp_path / "face.txt"
    path.write_text(GUIDE_EXAMPLE)
    labels = read_label_file(path)
    assert len(labels) == 8
    assert labels[0] == "Mouth_L_Corner" and labels[-1] == "Nose_Tip"


def test_several_per_line_tabs_blank_lines_crlf_and_bom(tmp_path: Path) -> None:
    path = tmp_path / "mixed.txt"
    path.write_bytes("\ufeffBrow_L Brow_R\tBrow_C\r\n\r\n   \r\nLip_U  Lip_D\r\nÉclat\r\n"
                     .encode("utf-8"))
    assert read_label_file(path) == ["Brow_L", "Brow_R", "Brow_C", "Lip_U", "Lip_D", "Éclat"]


def test_latin1_file_still_loads(tmp_path: Path) -> None:
    path = tmp_path / "old.txt"
    path.write_bytes("Lèvre_G Lèvre_D\n".encode("latin-1"))
    assert read_label_file(path) == ["Lèvre_G", "Lèvre_D"]


def test_bad_label_files(tmp_path: Path) -> None:
    with pytest.raises(CaraFileError, match="cannot be read"):
        read_label_file(tmp_path / "absent.txt")
    binary = tmp_path / "image.txt"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    with pytest.raises(CaraFileError, match="binary") as info:
        read_label_file(binary)
    assert info.value.path == binary
    empty = tmp_path / "empty.txt"
    empty.write_text("\n\n")
    assert read_label_file(empty) == []


def test_merge_appends_copy_then_numbers() -> None:
    existing = ["Nose_Tip", "Chin", "Chin - Copy"]
    new = ["Chin", "Brow", "Chin", "Nose_Tip", "Brow", "Chin - Copy"]
    assert merge_labels(existing, new) == [
        "Chin - Copy (2)", "Brow", "Chin - Copy (3)", "Nose_Tip - Copy", "Brow - Copy",
        "Chin - Copy - Copy",
    ]
    assert merge_labels([], ["A", "B"]) == ["A", "B"]


def test_merge_of_many_repeats_keeps_names_short() -> None:
    # 30,000 repeats (a 250 KB file of one name): chained suffixes would make names of
    # 200 KB (gigabytes in all); numbered copies stay short (timing: benchmarks/fuzz.py)
    names = merge_labels(["Nose_Tip"], ["Nose_Tip"] * 30_000)
    assert len(set(names)) == 30_000
    assert names[0] == "Nose_Tip - Copy" and names[-1] == "Nose_Tip - Copy (30000)"


@given(
    existing=st.lists(st.sampled_from(["A", "B", "A - Copy", "C"]), max_size=6),
    new=st.lists(st.sampled_from(["A", "B", "C", "D", "A - Copy"]), max_size=10),
)
def test_merge_gives_distinct_new_names(existing: list[str], new: list[str]) -> None:
    added = merge_labels(existing, new)
    assert len(added) == len(new)
    assert len(set(added)) == len(added)
    assert not set(added) & set(existing)
    for i, (original, name) in enumerate(zip(new, added, strict=True)):
        suffix = name[len(original):]
        assert name.startswith(original)
        m = re.fullmatch(r"( - Copy(?: \((\d+)\))?)?", suffix)
        assert m is not None, suffix
        # Minimal: the name itself, then every smaller copy number, is taken.
        taken = set(existing) | set(added[:i])
        if suffix:
            k = int(m.group(2) or 1)
            assert original in taken
            assert all(original + " - Copy" + ("" if j == 1 else f" ({j})") in taken
                       for j in range(1, k))
        else:
            assert original not in taken


def test_write_then_read_round_trip(tmp_path: Path) -> None:
    labels = ["Mouth_L_Corner", "Nose_Tip", "Éclat", "Chin_R_Pt2"]
    path = tmp_path / "out.txt"
    write_label_file(path, labels)
    assert read_label_file(path) == labels
    assert path.read_text(encoding="utf-8").splitlines() == labels


@pytest.mark.parametrize("bad", ["two words", "", " lead", "tab\there"])
def test_write_rejects_names_the_format_cannot_hold(tmp_path: Path, bad: str) -> None:
    path = tmp_path / "out.txt"
    with pytest.raises(ValueError, match="no spaces"):
        write_label_file(path, ["ok", bad])
    assert not path.exists()


def _cara(path: Path, manifest: object | None, raw: bytes | None = None) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        if raw is not None:
            zf.writestr("manifest.json", raw)
        elif manifest is not None:
            zf.writestr("manifest.json", json.dumps(manifest))
        zf.writestr("points.npy", b"\x93NUMPY")
    return path


def test_labels_from_cara(tmp_path: Path) -> None:
    path = _cara(tmp_path / "take.cara",
                 {"format_version": 1, "labels": ["Nose_Tip", {"name": "Chin"}]})
    assert read_labels_from_cara(path) == ["Nose_Tip", "Chin"]
    assert read_labels_from_cara(_cara(tmp_path / "none.cara", {"format_version": 1})) == []


@pytest.mark.parametrize(
    ("case", "pattern"),
    [
        ("not_zip", "not a ZIP"),
        ("no_manifest", "no manifest.json"),
        ("bad_json", "damaged manifest.json"),
        ("not_object", "not a JSON object"),
        ("labels_not_list", "'labels' is not a list"),
        ("label_not_name", "label 1 is not a name"),
    ],
)
def test_bad_cara_files(tmp_path: Path, case: str, pattern: str) -> None:
    path = tmp_path / f"{case}.cara"
    if case == "not_zip":
        path.write_text("Mouth_L_Corner Nose_Tip")
    elif case == "no_manifest":
        _cara(path, None)
    elif case == "bad_json":
        _cara(path, None, raw=b"{labels: [")
    elif case == "not_object":
        _cara(path, ["Nose_Tip"])
    elif case == "labels_not_list":
        _cara(path, {"labels": "Nose_Tip"})
    else:
        _cara(path, {"labels": ["Nose_Tip", 3]})
    with pytest.raises(CaraFileError, match=pattern) as info:
        read_labels_from_cara(path)
    assert str(path) in str(info.value)
