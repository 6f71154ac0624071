"""Point-file I/O (SPEC.md section 3, "Point files"): synthesis.points.

Covers reading text/CSV/.npy point files, the domain convention, round trips
through write_points, atomic writes, and that every malformed input raises
PointFileError whose message names the file and the line (or .npy row).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import synthesis.points as points_module
from synthesis.errors import PatternshopError, PointFileError
from synthesis.points import PointSet, check_domain, read_points, write_points


# --------------------------------------------------------------------------- helpers


def put(path: Path, content: str | bytes) -> Path:
    """Write ``content`` byte for byte (no newline translation) and return ``path``."""
    data = content.encode("utf-8") if isinstance(content, str) else content
    path.write_bytes(data)
    return path


def save_npy(path: Path, array: np.ndarray, allow_pickle: bool = False) -> Path:
    with open(path, "wb") as handle:
        np.save(handle, array, allow_pickle=allow_pickle)
    return path


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def nine_digits(values: np.ndarray) -> np.ndarray:
    """``values`` rounded to 9 significant digits, as text files store them."""
    return np.vectorize(lambda v: float(f"{v:.9g}"))(np.asarray(values, dtype=np.float64))


# --------------------------------------------------------------------------- reading text


@pytest.mark.parametrize(
    "text",
    [
        pytest.param("0.1 0.2\n0.3 0.4\n", id="spaces"),
        pytest.param("0.1   0.2\n  0.3 0.4  \n", id="runs-of-spaces"),
        pytest.param("0.1\t0.2\n0.3\t\t0.4\n", id="tabs"),
        pytest.param("0.1,0.2\n0.3,0.4\n", id="commas"),
        pytest.param("0.1, 0.2\n0.3 ,\t0.4\n", id="commas-and-spaces"),
        pytest.param("0.1 0.2\n0.3 0.4", id="no-final-newline"),
        pytest.param("0.1 0.2\r\n0.3 0.4\r\n", id="crlf"),
        pytest.param("\ufeff0.1 0.2\n0.3 0.4\n", id="bom"),
        pytest.param("\ufeff0.1,0.2\r\n0.3,0.4\r\n", id="bom-crlf-commas"),
        pytest.param("# a comment\n0.1 0.2\n\n# another\n   \n0.3 0.4\n\n", id="comments-and-blank-lines"),
        pytest.param("0.1 0.2 # first\n0.3 0.4#second\n", id="trailing-comments"),
        pytest.param("  # indented comment\n0.1 0.2\n0.3 0.4\n", id="indented-comment"),
        pytest.param("1e-1 2E-1\n3.0e-1 +0.4\n", id="exponents-and-sign"),
        pytest.param("x y\n0.1 0.2\n0.3 0.4\n", id="whitespace-header"),
        pytest.param("X,Y\n0.1,0.2\n0.3,0.4\n", id="uppercase-header"),
    ],
)
def test_read_text_layouts(tmp_path: Path, text: str) -> None:
    path = put(tmp_path / "points.txt", text)
    ps = read_points(path)
    assert isinstance(ps, PointSet)
    assert ps.xy.dtype == np.float64
    assert ps.xy.shape == (2, 2)
    np.testing.assert_array_equal(ps.xy, [[0.1, 0.2], [0.3, 0.4]])
    assert ps.radius is None
    assert ps.domain == (1.0, 1.0)
    assert len(ps) == 2


def test_read_accepts_str_path(tmp_path: Path) -> None:
    path = put(tmp_path / "points.txt", "0.5 0.5\n")
    np.testing.assert_array_equal(read_points(str(path)).xy, [[0.5, 0.5]])


@pytest.mark.parametrize("name", ["p.txt", "p.csv", "p.xy", "p.pts", "P.TXT", "p.CSV"])
def test_read_text_suffixes(tmp_path: Path, name: str) -> None:
    path = put(tmp_path / name, "0.25,0.75\n")
    np.testing.assert_array_equal(read_points(path).xy, [[0.25, 0.75]])


def test_read_text_radius_column(tmp_path: Path) -> None:
    path = put(tmp_path / "dots.txt", "# x y r\n0.1 0.2 0.01\n0.3 0.4 0\n0.5 0.6 0.125 # big\n")
    ps = read_points(path)
    np.testing.assert_array_equal(ps.xy, [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    assert ps.radius is not None and ps.radius.dtype == np.float64
    np.testing.assert_array_equal(ps.radius, [0.01, 0.0, 0.125])


@pytest.mark.parametrize(
    "text, radius",
    [
        pytest.param("x,y\n0.1,0.2\n0.3,0.4\n", None, id="x,y"),
        pytest.param("x,y,radius\n0.1,0.2,0.01\n0.3,0.4,0.02\n", [0.01, 0.02], id="x,y,radius"),
        pytest.param("\ufeffx,y,radius\r\n0.1,0.2,0.01\r\n0.3,0.4,0.02\r\n", [0.01, 0.02], id="excel-bom-crlf"),
        pytest.param("# exported\n\nx,y\n0.1,0.2\n0.3,0.4\n", None, id="header-after-comment"),
    ],
)
def test_read_csv_with_header(tmp_path: Path, text: str, radius: list[float] | None) -> None:
    ps = read_points(put(tmp_path / "points.csv", text))
    np.testing.assert_array_equal(ps.xy, [[0.1, 0.2], [0.3, 0.4]])
    if radius is None:
        assert ps.radius is None
    else:
        np.testing.assert_array_equal(ps.radius, radius)


def test_domain_boundary_is_inclusive(tmp_path: Path) -> None:
    ps = read_points(put(tmp_path / "corners.txt", "0 0\n1 0\n0 1\n1 1\n"))
    np.testing.assert_array_equal(ps.xy, [[0, 0], [1, 0], [0, 1], [1, 1]])


# --------------------------------------------------------------------------- reading .npy


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64, np.int32, np.uint8])
@pytest.mark.parametrize("columns", [2, 3])
def test_read_npy(tmp_path: Path, dtype: type, columns: int) -> None:
    if np.issubdtype(dtype, np.integer):
        array = np.array([[0, 1, 0], [1, 0, 1], [1, 1, 0]], dtype=dtype)[:, :columns]
    else:
        array = np.array([[0.1, 0.2, 0.01], [0.3, 0.4, 0.02], [1 / 3, 2 / 3, 0.0]], dtype=dtype)[:, :columns]
    ps = read_points(save_npy(tmp_path / "points.npy", array))
    expected = array.astype(np.float64)  # float32 values widened exactly, not re-rounded
    assert ps.xy.dtype == np.float64
    np.testing.assert_array_equal(ps.xy, expected[:, :2])
    if columns == 3:
        assert ps.radius is not None and ps.radius.dtype == np.float64
        np.testing.assert_array_equal(ps.radius, expected[:, 2])
    else:
        assert ps.radius is None
    assert ps.domain == (1.0, 1.0)


def test_read_npy_uppercase_suffix_and_fortran_order(tmp_path: Path) -> None:
    array = np.asfortranarray(np.array([[0.1, 0.9], [0.8, 0.05]]))
    ps = read_points(save_npy(tmp_path / "P.NPY", array))
    np.testing.assert_array_equal(ps.xy, array)


# --------------------------------------------------------------------------- origin and axes


def test_values_are_returned_as_given(tmp_path: Path) -> None:
    """Origin top-left, y down: the reader neither flips nor swaps anything."""
    xy = [[0.1, 0.9], [0.8, 0.05], [0.0, 1.0]]
    text = read_points(put(tmp_path / "p.txt", "0.1 0.9\n0.8 0.05\n0 1\n"))
    npy = read_points(save_npy(tmp_path / "p.npy", np.array(xy)))
    np.testing.assert_array_equal(text.xy, xy)
    np.testing.assert_array_equal(npy.xy, xy)


def test_second_column_is_y_bounded_by_height(tmp_path: Path) -> None:
    """In a wide domain (w=1, h=0.5) column 1 is x in [0, 1] and column 2 is y in [0, 0.5]."""
    ok = read_points(put(tmp_path / "ok.txt", "0.9 0.4\n"), domain=(1.0, 0.5))
    np.testing.assert_array_equal(ok.xy, [[0.9, 0.4]])
    with pytest.raises(PointFileError, match=r"\(0\.4, 0\.9\)"):
        read_points(put(tmp_path / "swapped.txt", "0.4 0.9\n"), domain=(1.0, 0.5))


# --------------------------------------------------------------------------- domain


def test_default_domain_is_unit_square(tmp_path: Path) -> None:
    assert read_points(put(tmp_path / "p.txt", "0.5 0.5\n")).domain == (1.0, 1.0)
    assert read_points(save_npy(tmp_path / "p.npy", np.array([[0.5, 0.5]]))).domain == (1.0, 1.0)
    assert PointSet(np.zeros((1, 2))).domain == (1.0, 1.0)


@pytest.mark.parametrize(
    "comment, domain",
    [
        ("# domain: 1 0.5", (1.0, 0.5)),
        ("# domain: 0.5 1", (0.5, 1.0)),
        ("#domain=1,0.25", (1.0, 0.25)),
        ("# Domain: 1 0.5", (1.0, 0.5)),
    ],
)
def test_domain_comment_sets_domain(tmp_path: Path, comment: str, domain: tuple[float, float]) -> None:
    path = put(tmp_path / "p.txt", f"{comment}\n0.1 0.2\n0.25 0.25\n")
    ps = read_points(path)
    assert ps.domain == domain
    assert all(isinstance(v, float) for v in ps.domain)


def test_domain_comment_rejects_points_beyond_height(tmp_path: Path) -> None:
    path = put(tmp_path / "p.txt", "# domain: 1 0.5\n0.2 0.5\n0.9 0.51\n")
    with pytest.raises(PointFileError) as info:
        read_points(path)
    message = str(info.value)
    assert message.startswith(f"{path}:3: ")
    assert "(0.9, 0.51)" in message
    assert "[0, 1] x [0, 0.5]" in message


def test_domain_comment_in_csv(tmp_path: Path) -> None:
    path = put(tmp_path / "p.csv", "# domain: 0.5 1\nx,y\n0.5,1\n")
    assert read_points(path).domain == (0.5, 1.0)


def test_domain_argument_overrides_comment(tmp_path: Path) -> None:
    path = put(tmp_path / "p.txt", "# domain: 1 0.5\n0.2 0.75\n")
    ps = read_points(path, domain=(1.0, 1.0))
    assert ps.domain == (1.0, 1.0)
    np.testing.assert_array_equal(ps.xy, [[0.2, 0.75]])
    with pytest.raises(PointFileError, match=r"outside the domain \[0, 0\.5\] x \[0, 1\]"):
        read_points(put(tmp_path / "q.txt", "# domain: 1 0.5\n0.75 0.2\n"), domain=(0.5, 1.0))


def test_domain_argument_for_npy(tmp_path: Path) -> None:
    path = save_npy(tmp_path / "p.npy", np.array([[0.4, 0.9], [0.1, 0.1]]))
    assert read_points(path, domain=(0.5, 1.0)).domain == (0.5, 1.0)
    with pytest.raises(PointFileError) as info:
        read_points(path, domain=(1.0, 0.5))
    assert str(info.value).startswith(f"{path}: row 1: ")
    assert "[0, 1] x [0, 0.5]" in str(info.value)


BAD_DOMAINS = [
    pytest.param((2.0, 1.0), id="max-2"),
    pytest.param((1.0, 1.5), id="h-too-long"),
    pytest.param((0.5, 0.5), id="max-half"),
    pytest.param((-1.0, 1.0), id="negative-w"),
    pytest.param((1.0, -0.5), id="negative-h"),
    pytest.param((0.0, 1.0), id="zero-w"),
    pytest.param((1.0, 0.0), id="zero-h"),
    pytest.param((math.nan, 1.0), id="nan"),
    pytest.param((1.0, math.inf), id="inf"),
]


@pytest.mark.parametrize("domain", BAD_DOMAINS)
def test_check_domain_rejects(domain: tuple[float, float]) -> None:
    with pytest.raises(PointFileError, match="max\\(w, h\\) = 1"):
        check_domain(domain)


@pytest.mark.parametrize("domain", BAD_DOMAINS)
def test_read_points_rejects_bad_domain_argument(tmp_path: Path, domain: tuple[float, float]) -> None:
    path = put(tmp_path / "p.txt", "0 0\n")
    with pytest.raises(PointFileError) as info:
        read_points(path, domain=domain)
    assert str(info.value).startswith(f"{path}: ")
    assert "domain" in str(info.value)


@pytest.mark.parametrize("domain", BAD_DOMAINS)
def test_pointset_rejects_bad_domain(domain: tuple[float, float]) -> None:
    with pytest.raises(PointFileError):
        PointSet(np.zeros((1, 2)), domain)


@pytest.mark.parametrize(
    "domain, expected",
    [((1, 1), (1.0, 1.0)), ((1, 0.5), (1.0, 0.5)), ((0.25, 1), (0.25, 1.0)), (np.array([1.0, 0.75]), (1.0, 0.75))],
)
def test_check_domain_accepts(domain, expected) -> None:
    result = check_domain(domain)
    assert result == expected
    assert all(type(v) is float for v in result)


def test_pointset_radius_count_must_match() -> None:
    with pytest.raises(PointFileError, match="2 radii for 3 points"):
        PointSet(np.zeros((3, 2)), radius=[0.1, 0.2])


# --------------------------------------------------------------------------- round trips

ROUND_TRIP_SUFFIXES = [".txt", ".csv", ".npy", ".xy", ".pts"]
KEEPS_DOMAIN = {".txt", ".xy", ".pts"}


def _sample(domain: tuple[float, float], with_radius: bool) -> PointSet:
    w, h = domain
    rng = np.random.default_rng(1234)
    xy = rng.random((50, 2)) * [w, h]
    # awkward values: corners, tiny, exactly representable and not, many digits
    xy[:6] = [[0.0, 0.0], [w, h], [w, 0.0], [1e-9, h / 3], [w / 7, 1.23456789012345e-5], [0.1, 0.2 * h]]
    radius = rng.random(50) * 0.01 if with_radius else None
    if radius is not None:
        radius[:2] = [0.0, 1 / 3]
    return PointSet(xy, domain, radius)


@pytest.mark.parametrize("domain", [(1.0, 1.0), (1.0, 0.5), (0.625, 1.0)], ids=["square", "wide", "tall"])
@pytest.mark.parametrize("with_radius", [False, True], ids=["xy", "radius"])
@pytest.mark.parametrize("suffix", ROUND_TRIP_SUFFIXES)
def test_round_trip(tmp_path: Path, suffix: str, with_radius: bool, domain: tuple[float, float]) -> None:
    original = _sample(domain, with_radius)
    path = tmp_path / f"out{suffix}"
    write_points(original, path)
    assert listing(tmp_path) == [path.name], "no temporary files left behind"

    if suffix in KEEPS_DOMAIN:
        back = read_points(path)
        assert back.domain == domain
    else:
        back = read_points(path, domain=domain)
        assert back.domain == domain
        # without the argument these formats fall back to the unit square
        assert read_points(path).domain == (1.0, 1.0)

    assert back.xy.shape == original.xy.shape
    if suffix == ".npy":
        np.testing.assert_array_equal(back.xy, original.xy)
    else:
        np.testing.assert_array_equal(back.xy, nine_digits(original.xy))
        np.testing.assert_allclose(back.xy, original.xy, rtol=5e-9, atol=0)
    if with_radius:
        assert back.radius is not None
        if suffix == ".npy":
            np.testing.assert_array_equal(back.radius, original.radius)
        else:
            np.testing.assert_array_equal(back.radius, nine_digits(original.radius))
    else:
        assert back.radius is None


def test_written_txt_layout(tmp_path: Path) -> None:
    path = tmp_path / "out.txt"
    write_points(PointSet([[0.1, 0.2], [0.3, 0.4]], (1.0, 0.5), [0.01, 0.02]), path)
    lines = path.read_text(encoding="utf-8").splitlines()
    comments = [line for line in lines if line.startswith("#")]
    data = [line for line in lines if line.strip() and not line.startswith("#")]
    assert any(line.replace(" ", "") == "#domain:10.5" for line in comments)
    assert any("y down" in line for line in comments)
    assert [line.split() for line in data] == [["0.1", "0.2", "0.01"], ["0.3", "0.4", "0.02"]]


@pytest.mark.parametrize("with_radius, header", [(False, "x,y"), (True, "x,y,radius")])
def test_written_csv_layout(tmp_path: Path, with_radius: bool, header: str) -> None:
    path = tmp_path / "out.csv"
    write_points(PointSet([[0.1, 0.2]], radius=[0.05] if with_radius else None), path)
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0] == header
    assert lines[1] == ("0.1,0.2,0.05" if with_radius else "0.1,0.2")


def test_written_npy_is_plain_float_table(tmp_path: Path) -> None:
    path = tmp_path / "out.npy"
    write_points(PointSet([[0.1, 0.2]], radius=[0.05]), path)
    array = np.load(path, allow_pickle=False)
    assert array.dtype == np.float64
    np.testing.assert_array_equal(array, [[0.1, 0.2, 0.05]])


def test_write_replaces_existing_file(tmp_path: Path) -> None:
    path = put(tmp_path / "out.txt", "old content that is longer than the new one " * 100)
    write_points(PointSet([[0.5, 0.5]]), path)
    np.testing.assert_array_equal(read_points(path).xy, [[0.5, 0.5]])
    assert listing(tmp_path) == ["out.txt"]


def test_write_unsupported_suffix(tmp_path: Path) -> None:
    path = tmp_path / "out.json"
    with pytest.raises(PointFileError) as info:
        write_points(PointSet([[0.5, 0.5]]), path)
    assert str(path) in str(info.value)
    assert "'.json'" in str(info.value)
    assert listing(tmp_path) == []


# --------------------------------------------------------------------------- atomic writes


def test_write_to_missing_folder_creates_nothing(tmp_path: Path) -> None:
    target = tmp_path / "missing" / "out.txt"
    with pytest.raises(OSError):  # the CLI reports OSError like a PatternshopError
        write_points(PointSet([[0.5, 0.5]]), target)
    assert not target.parent.exists()
    assert listing(tmp_path) == []


class Boom(RuntimeError):
    pass


def _failing_writer(fname, *args, **kwargs):
    """Stand-in for numpy.savetxt / numpy.save: writes half a file, then fails."""
    if hasattr(fname, "write"):
        fname.write(b"half a file")
    else:
        Path(fname).write_bytes(b"half a file")
    raise Boom("disk full")


@pytest.mark.parametrize("suffix, function", [(".txt", "savetxt"), (".csv", "savetxt"), (".npy", "save")])
def test_failed_write_keeps_existing_target(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, suffix: str, function: str
) -> None:
    target = tmp_path / f"out{suffix}"
    write_points(PointSet([[0.25, 0.75]]), target)
    before = target.read_bytes()
    monkeypatch.setattr(points_module.np, function, _failing_writer)
    with pytest.raises(Boom):
        write_points(PointSet([[0.5, 0.5], [0.1, 0.1]]), target)
    monkeypatch.undo()
    assert target.read_bytes() == before
    assert listing(tmp_path) == [target.name], "no temporary files left behind"
    np.testing.assert_array_equal(read_points(target).xy, [[0.25, 0.75]])


def test_failed_write_creates_no_target(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(points_module.np, "savetxt", _failing_writer)
    with pytest.raises(Boom):
        write_points(PointSet([[0.5, 0.5]]), tmp_path / "new.txt")
    assert listing(tmp_path) == []


# --------------------------------------------------------------------------- malformed input
#
# Each case: file name, content (str/bytes, or a callable writing the file),
# where the error is ("LINE" for text -> "PATH:LINE: ", "row N" for .npy ->
# "PATH: row N: ", None -> "PATH: "), and substrings the message must contain.


def _npy(array, allow_pickle: bool = False):
    return lambda path: save_npy(path, np.asarray(array), allow_pickle)


def _truncated_npy(path: Path) -> None:
    save_npy(path, np.linspace(0, 1, 200).reshape(100, 2))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


MALFORMED = [
    # column counts
    pytest.param("p.txt", "# one column\n0.5\n", "2", ["expected 2 or 3 columns", "got 1"], id="one-column"),
    pytest.param("p.txt", "0.1 0.2 0.3 0.4\n", "1", ["expected 2 or 3 columns", "got 4"], id="four-columns"),
    pytest.param("p.csv", "x,y\n0.1,0.2,0.3,0.4\n", "2", ["got 4"], id="four-columns-csv"),
    pytest.param(
        "p.txt", "0.1 0.2\n0.3 0.4\n# note\n\n0.5 0.6 0.01\n", "5",
        ["expected 2 columns", "got 3"], id="three-after-two",
    ),
    pytest.param(
        "p.txt", "0.1 0.2 0.01\n0.3 0.4 0.02\n0.5 0.6\n", "3",
        ["expected 3 columns", "got 2"], id="two-after-three",
    ),
    pytest.param("p.txt", "0.1 0.2\n0.3\n", "2", ["expected 2 columns", "got 1"], id="one-after-two"),
    # non-numbers
    pytest.param("p.txt", "0.1 0.2\n0.3 abc\n", "2", ["'abc'", "not a number"], id="word"),
    pytest.param("p.csv", "0.1,0.2\n0.3,0.4x\n", "2", ["'0.4x'", "not a number"], id="suffix-garbage"),
    pytest.param("p.txt", "0.1 0.2\n0,3 0.4\n", "2", ["got 3"], id="decimal-comma"),
    pytest.param("p.csv", "0.1;0.2\n", "1", ["expected 2 or 3 columns", "got 1"], id="semicolons"),
    pytest.param("p.txt", "0.1 0.2 big\n", "1", ["'big'", "not a number"], id="word-in-radius"),
    pytest.param("p.csv", "0.1,0.2\nx,y\n", "2", ["'x'", "not a number"], id="header-after-data"),
    pytest.param("p.csv", "0.1,,0.2\n", "1", ["empty field"], id="empty-csv-field"),
    pytest.param("p.csv", "0.1,0.2,\n", "1", ["empty field"], id="trailing-comma"),
    pytest.param("p.csv", "x,y,radius\n0.1,0.2\n", "2", ["expected 3 columns", "got 2"], id="header-fixes-columns"),
    # non-finite values
    pytest.param("p.txt", "0.1 0.2\n0.3 nan\n", "2", ["non-finite", "nan"], id="nan"),
    pytest.param("p.txt", "0.1 0.2\ninf 0.4\n", "2", ["non-finite", "inf"], id="inf"),
    pytest.param("p.txt", "0.1 0.2\n0.3 -inf\n", "2", ["non-finite", "-inf"], id="minus-inf"),
    pytest.param("p.txt", "0.1 0.2 NaN\n", "1", ["non-finite"], id="nan-radius"),
    # outside the domain
    pytest.param(
        "p.txt", "0.5 0.5\n-0.1 0.5\n", "2",
        ["(-0.1, 0.5)", "outside the domain", "[0, 1] x [0, 1]"], id="x-negative",
    ),
    pytest.param(
        "p.txt", "1.5 0.5\n", "1", ["(1.5, 0.5)", "outside the domain", "[0, 1] x [0, 1]"], id="x-above-1",
    ),
    pytest.param("p.txt", "0.5 -0.25\n", "1", ["(0.5, -0.25)", "outside the domain"], id="y-negative"),
    pytest.param("p.txt", "0.5 1.25\n", "1", ["(0.5, 1.25)", "outside the domain"], id="y-above-1"),
    pytest.param(
        "p.txt", "# domain: 1 0.5\n0.5 0.25\n\n0.5 0.75\n", "4",
        ["(0.5, 0.75)", "[0, 1] x [0, 0.5]"], id="y-above-h",
    ),
    pytest.param(
        "p.txt", "# domain: 0.5 1\n0.25 0.5\n0.75 0.5\n", "3",
        ["(0.75, 0.5)", "[0, 0.5] x [0, 1]"], id="x-above-w",
    ),
    pytest.param(
        "p.txt", "0.5 0.5\n2 2\n3 3\n", "2", ["(2, 2)", "2 points outside"], id="first-of-several-outside",
    ),
    pytest.param("p.txt", "0.1 0.2 -0.01\n", "1", ["negative radius", "-0.01"], id="negative-radius"),
    # domain comments
    pytest.param("p.txt", "0.1 0.2\n# domain: 2 1\n", "2", ["bad domain comment"], id="domain-comment-max-2"),
    pytest.param("p.txt", "# domain: 1 0\n0.1 0.2\n", "1", ["bad domain comment"], id="domain-comment-zero"),
    pytest.param("p.txt", "# domain: a b\n0.1 0.2\n", "1", ["bad domain comment"], id="domain-comment-words"),
    # empty
    pytest.param("p.txt", "", None, ["no points"], id="empty"),
    pytest.param("p.txt", "\n  \n\t\n", None, ["no points"], id="blank-lines-only"),
    pytest.param("p.txt", "# just\n# comments\n\n", None, ["no points"], id="comments-only"),
    pytest.param("p.csv", "x,y,radius\n", None, ["no points"], id="header-only"),
    # not text
    pytest.param("p.txt", b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe\xfd", None, ["not a text file"], id="binary-txt"),
    pytest.param("p.txt", "0.1 0.2\n".encode("utf-16"), None, ["not a text file"], id="utf16-txt"),
    pytest.param("p.txt", b"0.1 0.2\n0.3 0.4 caf\xe9\n", None, ["not a text file"], id="latin1-txt"),
    # .npy
    pytest.param("p.npy", _npy(np.zeros((3, 4))), None, ["(n, 2) or (n, 3)", "(3, 4)"], id="npy-n-by-4"),
    pytest.param("p.npy", _npy(np.zeros((3, 1))), None, ["(n, 2) or (n, 3)", "(3, 1)"], id="npy-n-by-1"),
    pytest.param("p.npy", _npy(np.zeros(6)), None, ["(n, 2) or (n, 3)", "(6,)"], id="npy-1d"),
    pytest.param("p.npy", _npy(np.zeros((2, 3, 2))), None, ["(n, 2) or (n, 3)", "(2, 3, 2)"], id="npy-3d"),
    pytest.param("p.npy", _npy(np.float64(0.5)), None, ["(n, 2) or (n, 3)"], id="npy-scalar"),
    pytest.param("p.npy", b"this is not a numpy file at all", None, ["not a readable .npy file"], id="npy-junk"),
    pytest.param("p.npy", b"", None, ["not a readable .npy file"], id="npy-zero-bytes"),
    pytest.param("p.npy", _truncated_npy, None, ["not a readable .npy file"], id="npy-truncated"),
    pytest.param("p.npy", _npy([["0.1", "0.2"]]), None, ["expected real numbers"], id="npy-strings"),
    pytest.param(
        "p.npy", _npy(np.array([[0.1, None]], dtype=object), allow_pickle=True), None,
        ["not a readable .npy file"], id="npy-objects",
    ),
    pytest.param("p.npy", _npy(np.array([[True, False]])), None, ["expected real numbers"], id="npy-bool"),
    pytest.param("p.npy", _npy(np.array([[0.1 + 0j, 0.2]])), None, ["expected real numbers"], id="npy-complex"),
    pytest.param("p.npy", _npy(np.zeros((0, 2))), None, ["no points"], id="npy-empty"),
    pytest.param("p.npy", _npy([[0.1, 0.2], [np.nan, 0.3]]), "row 2", ["non-finite"], id="npy-nan"),
    pytest.param("p.npy", _npy([[0.1, 0.2], [0.3, -np.inf]]), "row 2", ["non-finite"], id="npy-inf"),
    pytest.param(
        "p.npy", _npy([[0.1, 0.2], [0.3, 0.4], [1.5, 0.5]]), "row 3",
        ["(1.5, 0.5)", "outside the domain", "[0, 1] x [0, 1]"], id="npy-outside",
    ),
    pytest.param("p.npy", _npy([[0.1, 0.2, 0.0], [0.3, 0.4, -1.0]]), "row 2", ["negative radius"], id="npy-neg-radius"),
    # format
    pytest.param("p.json", '[[0.1, 0.2]]', None, ["unsupported point format", "'.json'"], id="json-suffix"),
    pytest.param("points", "0.1 0.2\n", None, ["unsupported point format"], id="no-suffix"),
]


@pytest.mark.parametrize("name, content, where, fragments", MALFORMED)
def test_malformed(tmp_path: Path, name: str, content, where: str | None, fragments: list[str]) -> None:
    path = tmp_path / name
    if callable(content):
        content(path)
    else:
        put(path, content)
    with pytest.raises(PointFileError) as info:
        read_points(path)
    message = str(info.value)
    if where is None:
        prefix = f"{path}: "
    elif where.startswith("row"):
        prefix = f"{path}: {where}: "
    else:
        prefix = f"{path}:{where}: "
    assert message.startswith(prefix), message
    for fragment in fragments:
        assert fragment in message, message
    assert "\n" not in message, "one-line message"
    assert isinstance(info.value, PatternshopError)


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.txt"
    with pytest.raises(PointFileError) as info:
        read_points(path)
    assert str(info.value).startswith(f"{path}: ")
    assert "no such file" in str(info.value)


def test_directory_is_not_a_point_file(tmp_path: Path) -> None:
    folder = tmp_path / "dir.txt"
    folder.mkdir()
    with pytest.raises(PointFileError, match="dir.txt"):
        read_points(folder)


# --------------------------------------------------------------------------- line numbers


@pytest.mark.parametrize(
    "text",
    [
        pytest.param("# header\n\n0.1 0.2\n   \n0.3 oops\n", id="lf"),
        pytest.param("# header\r\n\r\n0.1 0.2\r\n   \r\n0.3 oops\r\n", id="crlf"),
        pytest.param("\ufeff# header\n\n0.1 0.2\n   \n0.3 oops\n", id="bom"),
        pytest.param("x y\n# c\n0.1 0.2 # c\n\n0.3 oops # c\n", id="header-and-trailing-comments"),
    ],
)
def test_line_numbers_count_comments_and_blank_lines(tmp_path: Path, text: str) -> None:
    path = put(tmp_path / "p.txt", text)
    with pytest.raises(PointFileError) as info:
        read_points(path)
    assert str(info.value).startswith(f"{path}:5: 'oops' is not a number")


def test_line_number_of_late_error_in_long_file(tmp_path: Path) -> None:
    lines = ["# generated"] + [f"{i / 1000:.3f} 0.5" for i in range(998)] + ["0.5 0.5 0.5"]
    path = put(tmp_path / "p.txt", "\n".join(lines) + "\n")
    with pytest.raises(PointFileError) as info:
        read_points(path)
    assert str(info.value).startswith(f"{path}:1000: expected 2 columns")


@pytest.mark.parametrize("odd", ["\x0c", "\x85", "\u2028"], ids=["form-feed", "NEL", "LINE-SEPARATOR"])
def test_line_numbers_only_break_at_newlines(tmp_path: Path, odd: str) -> None:
    path = put(tmp_path / "p.txt", f"0.1 0.2 # note{odd}0.9 0.9\n0.3 oops\n")
    with pytest.raises(PointFileError) as info:
        read_points(path)
    assert str(info.value).startswith(f"{path}:2: 'oops' is not a number")


def test_npz_disguised_as_npy(tmp_path: Path) -> None:
    path = tmp_path / "p.npy"
    with open(path, "wb") as handle:
        np.savez(handle, xy=np.zeros((2, 2)))
    with pytest.raises(PointFileError, match="p.npy"):
        read_points(path)


def test_pointset_rejects_wrong_shapes() -> None:
    with pytest.raises(PointFileError, match=r"\(n, 2\)"):
        PointSet(np.zeros((2, 3)))
    with pytest.raises(PointFileError, match="two numbers"):
        check_domain((1.0,))


def test_domain_argument_may_be_an_array(tmp_path: Path) -> None:
    path = put(tmp_path / "p.txt", "0.5 0.25\n")
    assert read_points(path, domain=np.array([1.0, 0.5])).domain == (1.0, 0.5)


_ODD_FILES = {
    "written": None,  # write_points' own output, set in the test
    "exponents": "# domain: 1 0.5\n8.78668054e-05 0.25\n1e-07 4.2e-01\n0.5 1E-3\n",
    "radius": "0.1 0.2 0.01\n0.3 0.4 0\n",
    "no_final_newline": "0.1 0.2\n0.3 0.4",
    "tabs_and_spaces": "  0.1\t0.2  \n0.3    0.4\n",
    "blank_line": "# x y\n0.1 0.2\n\n0.3 0.4\n",
    "spaces_only_line": "0.1 0.2\n   \n0.3 0.4\n",
    "crlf": "# domain: 1 1\r\n0.1 0.2\r\n0.3 0.4\r\n",
    "inline_comment": "0.1 0.2 # first\n0.3 0.4\n",
    "late_comment": "0.1 0.2\n# points_per_ink: 500\n0.3 0.4\n",
    "commas": "0.1,0.2\n0.3,0.4\n",
    "csv_header": "x y\n0.1 0.2\n",
    "one_column": "0.1\n0.3\n",
    "ragged": "0.1 0.2\n0.3 0.4 0.5\n",
    "four_columns": "0.1 0.2 0.3 0.4\n",
    "word": "0.1 abc\n",
    "nan": "0.1 nan\n",
    "outside": "# domain: 1 0.5\n0.1 0.2\n0.3 0.9\n",
    "form_feed": "0.1 0.2\x0c\n0.3 0.4\n",
    "unicode_space": "0.1\u20030.2\n",
    "bom": "\ufeff# points_per_ink: 1200\n0.1 0.2\n",
    "header_only": "# domain: 1 1\n",
    "bad_scale": "# points_per_ink: -3\n0.1 0.2\n",
}


def _read_or_error(path: Path) -> tuple:
    """What read_points makes of a file: (xy bytes, radius bytes, domain, points per ink) or the error's text."""
    try:
        points = read_points(path, allow_empty=True)
    except PointFileError as exc:
        return ("error", str(exc))
    radius = None if points.radius is None else points.radius.tobytes()
    return points.xy.tobytes(), radius, points.domain, points.points_per_ink


@pytest.mark.parametrize("name", sorted(_ODD_FILES))
def test_fast_parser_is_the_plain_one(tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """read_points with the one-piece fast path (synthesis.points._parse_numbers) against the line-by-line parsers
    alone: the same values bit for bit, the same header, or the same error naming the same line."""
    path = tmp_path / "points.txt"
    if _ODD_FILES[name] is None:
        rng = np.random.default_rng(7)
        xy = rng.random((3000, 2)) * [1.0, 0.75]
        xy[:10] *= 1e-6  # %.9g writes these with exponents
        write_points(PointSet(xy, (1.0, 0.75), radius=rng.random(3000) * 1e-3, points_per_ink=41911.8105), path)
        assert points_module._parse_numbers(path, path.read_text()) is not None  # the fast path reads it
    else:
        put(path, _ODD_FILES[name])
    fast = _read_or_error(path)
    monkeypatch.setattr(points_module, "_parse_numbers", lambda path, text: None)
    assert fast == _read_or_error(path)
