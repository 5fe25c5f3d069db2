"""Run folders and thrust tables as spreadsheets, editors and hands write them.

Each case is the exact file text (bytes where the encoding matters) that a spreadsheet
or editor produces, with its source beside it, and what the readers must make of it:
valid input read to the same values as the tidy form, invalid input refused with one
line naming the file and the line. Formats: docs/run-format.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from common.errors import UserError
from common.runfolder import read_run
from common.thrust_table import ThrustTable
from tests.support.cli import run_in_process

TIDY_COMMANDS = b"t,d1,d2,d3,d4\n0,50,50,0,0\n1,20,0,20,0\n2,0,0,0,0\n"
TIDY_POSES = b"t,x,y,psi\n0,0,0,0\n0.5,0.01,-0.02,0.1\n1,0.04,-0.05,0.3\n2,0.1,-0.1,3.1\n"
CMD_T = [0.0, 1.0, 2.0]
DUTY = [[50, 50, 0, 0], [20, 0, 20, 0], [0, 0, 0, 0]]
POSE = [[0, 0, 0], [0.01, -0.02, 0.1], [0.04, -0.05, 0.3], [0.1, -0.1, 3.1]]


def make_run(tmp_path, commands=TIDY_COMMANDS, poses=TIDY_POSES, run_json=None):
    p = tmp_path / "run"
    p.mkdir(exist_ok=True)
    (p / "commands.csv").write_bytes(commands)
    (p / "poses.csv").write_bytes(poses)
    if run_json is not None:
        (p / "run.json").write_bytes(run_json)
    return p


def assert_tidy(run):
    np.testing.assert_array_equal(run.cmd_t, CMD_T)
    np.testing.assert_array_equal(run.duty_pct, DUTY)
    np.testing.assert_array_equal(run.pose, POSE)


def refused(p, match):
    with pytest.raises(UserError, match=match) as ei:
        read_run(p)
    assert "\n" not in str(ei.value)
    return str(ei.value)


# ------------------------------------------------------------ valid: read as is
@pytest.mark.parametrize("name, commands", [
    # CRLF: Excel on Windows ends CSV rows with CR LF (mschaef.com/cr-lf "Excel, CR/LF, and
    # CSV"; manual.vtenext.ch "CRLF ... Traditional Windows standard")
    ("crlf", TIDY_COMMANDS.replace(b"\n", b"\r\n")),
    # CR alone: Excel's "CSV (Macintosh)" / classic Mac (manual.vtenext.ch "CR (\r) -
    # Carriage Return Classic Mac standard")
    ("cr", TIDY_COMMANDS.replace(b"\n", b"\r")),
    # Excel "CSV UTF-8 (Comma delimited)" starts with EF BB BF (donatstudios.com/CSV-An-
    # Encoding-Nightmare; dev-toolbox.tech excel-csv-export: header read as "\ufeffname")
    ("utf8 bom", b"\xef\xbb\xbf" + TIDY_COMMANDS.replace(b"\n", b"\r\n")),
    # trailing blank lines (an editor's final newlines; validatethis.org/csv-error/empty-line)
    ("trailing blank lines", TIDY_COMMANDS + b"\n\n\r\n"),
    # rows of empty cells: spreadsheet rows that were edited and cleared are written as
    # separators only (the ",,"-padded rows of nifi ConvertExcelToCSVProcessor's example)
    ("rows of empty cells", TIDY_COMMANDS + b",,,,\n,,,,\n"),
    ("blank line inside", b"t,d1,d2,d3,d4\n0,50,50,0,0\n\n1,20,0,20,0\n2,0,0,0,0\n"),
    ("columns in another order", b"d4,d3,d2,d1,t\n0,0,50,50,0\n0,20,0,20,1\n0,0,0,0,2\n"),
    ("extra columns", b"t,note,d1,d2,d3,d4,pressure_psi\n0,start,50,50,0,0,60\n1,,20,0,20,0,59.5\n"
                      b"2,end,0,0,0,0,59\n"),
    ("spaces after commas", b"t, d1, d2, d3, d4\n0, 50, 50, 0, 0\n1, 20, 0, 20, 0\n2, 0, 0, 0, 0\n"),
    ("spaces before commas", b"t ,d1 ,d2 ,d3 ,d4\n0 ,50 ,50 ,0 ,0\n1 ,20 ,0 ,20 ,0\n2 ,0 ,0 ,0 ,0\n"),
    # Excel quotes fields when asked to or when a header has spaces; LibreOffice "Quote all
    # text cells" quotes the header
    ("quoted header", b'"t","d1","d2","d3","d4"\n0,50,50,0,0\n1,20,0,20,0\n2,0,0,0,0\n'),
    ("quoted values", b'"t","d1","d2","d3","d4"\n"0","50","50","0","0"\n"1","20","0","20","0"\n'
                      b'"2","0","0","0","0"\n'),
    # Excel's scientific format writes 5.00E+01
    ("scientific", b"t,d1,d2,d3,d4\n0.00E+00,5.00E+01,5.00E+01,0,0\n1,2.0E+01,0,2.0E+01,0\n2,0,0,0,0\n"),
    # a trailing comma on every row, header included
    ("trailing comma everywhere", b"t,d1,d2,d3,d4,\n0,50,50,0,0,\n1,20,0,20,0,\n2,0,0,0,0,\n"),
    # a trailing comma on data rows only: pandas then takes the first column as the index
    # and shifts every value one column left (pandas-dev/pandas#14124, pydata/pandas#2442;
    # the read_csv docs: "index_col=False can be used ... when you have a malformed file
    # with delimiters at the end of each line"). Was refused (d4 NaN) or, with a number
    # after the comma, read shifted without a word (see the next test).
    ("trailing comma on rows", b"t,d1,d2,d3,d4\n0,50,50,0,0,\n1,20,0,20,0,\n2,0,0,0,0,\n"),
    # Excel's plain "CSV (Comma delimited)" is in the Windows code page (donatstudios.com:
    # "uses your locale's Windows or Mac codepage. Win-1252"): a degree sign is byte 0xB0,
    # not UTF-8. In an extra column it does not matter. Was refused ("not a readable CSV").
    ("cp1252 in an extra column", "t,d1,d2,d3,d4,note\n0,50,50,0,0,20 °C\n1,20,0,20,0,\n"
                                  "2,0,0,0,0,\n".encode("cp1252")),
])
def test_spreadsheet_commands_read_as_the_tidy_file(tmp_path, name, commands):
    assert_tidy(read_run(make_run(tmp_path, commands=commands)))


def test_trailing_values_without_a_header_do_not_shift_the_columns(tmp_path):
    # pandas-dev/pandas#14124 with numbers after the last comma: before, t was read from
    # d1, x from d2 ... and accepted (times 0.01, 0.04, 0.1 increase).
    poses = b"t,x,y,psi\n0,0,0,0,7\n0.5,0.01,-0.02,0.1,7\n1,0.04,-0.05,0.3,7\n2,0.1,-0.1,3.1,7\n"
    assert_tidy(read_run(make_run(tmp_path, poses=poses)))


def test_excel_style_copy_of_a_simulated_run_reads_the_same(tmp_path):
    from common.runfolder import write_run

    t = np.array([0.0, 0.7, 1.9, 3.0])
    duty = np.array([[50, 50, 0, 0], [20, 0, 20, 0], [33.25, 10, 90, 0], [0, 0, 0, 0]])
    pt = np.linspace(0, 3, 31)
    pose = np.column_stack([0.01 * pt, -0.02 * pt ** 2, np.sin(pt)])
    tidy = read_run(write_run(tmp_path / "tidy", cmd_t=t, duty_pct=duty, pose_t=pt, pose=pose))
    excel = tmp_path / "excel"
    excel.mkdir()
    for f in ("commands.csv", "poses.csv"):
        text = (tmp_path / "tidy" / f).read_text()
        head, *rows = text.splitlines()
        out = '"' + head.replace(",", '","') + '",comment\r\n' + "".join(r.replace(",", ", ") + ",\r\n" for r in rows)
        empty_row = "," * (head.count(",") + 1)       # every cell of the row cleared
        (excel / f).write_bytes(b"\xef\xbb\xbf" + (out + empty_row + "\r\n\r\n").encode())
    got = read_run(excel)
    for a in ("cmd_t", "duty_pct", "pose_t", "pose"):
        np.testing.assert_array_equal(getattr(got, a), getattr(tidy, a))


def test_run_json_with_a_bom(tmp_path):
    # Notepad and PowerShell write UTF-8 with a BOM; json.loads then fails with "Unexpected
    # UTF-8 BOM (decode using utf-8-sig)" (Nayjest/lm-proxy#79). run.json is optional and
    # its content harmless: read it. Was: the whole run refused.
    p = make_run(tmp_path, run_json=b'\xef\xbb\xbf{\r\n  "kind": "hand",\r\n  "note": "60 psi"\r\n}\r\n')
    assert read_run(p).meta == {"kind": "hand", "note": "60 psi"}


# ------------------------------------------------------------------ refused
def test_blank_lines_do_not_shift_the_line_numbers(tmp_path):
    # Was: "line 3" for the bad value on line 4 (pandas skips the blank line, rows were
    # numbered without it).
    cmds = b"t,d1,d2,d3,d4\n0,50,50,0,0\n\n1,x,0,20,0\n2,0,0,0,0\n"
    refused(make_run(tmp_path, commands=cmds), r"commands.csv: line 4: column d1 is not a finite number \('x'\)$")
    cmds = b"\r\nt,d1,d2,d3,d4\r\n0,50,50,0,0\r\n\r\n1,20,0,120,0\r\n2,0,0,0,0\r\n"
    refused(make_run(tmp_path, commands=cmds), r"commands.csv: line 5: duty outside 0..100 %$")
    poses = TIDY_POSES.replace(b"0.5,", b"\n\n0.5,").replace(b"\n2,", b"\n3,")
    refused(make_run(tmp_path, poses=poses), r"poses.csv: line 7: pose time 3 s lies outside")


@pytest.mark.parametrize("cell, shown", [
    (b"", "empty cell"),       # was shown as np.float64(nan)
    (b"NA", "'NA'"),           # pandas' default NA strings: the text as written
    (b"N/A", "'N/A'"),
    (b"#DIV/0!", "'#DIV/0!'"),  # an Excel error value exported as text (dev-toolbox.tech)
])
def test_bad_cells_are_named_as_written(tmp_path, cell, shown):
    cmds = b"t,d1,d2,d3,d4\n0,50,50,0,0\n1," + cell + b",0,20,0\n2,0,0,0,0\n"
    refused(make_run(tmp_path, commands=cmds), rf"commands.csv: line 3: column d1 is not a finite number \({shown}\)$")


def test_decimal_comma_is_refused_naming_the_line(tmp_path):
    # A decimal comma (German/French Excel, dev-toolbox.tech excel-csv-export): unquoted it
    # makes one row a field longer than the others, quoted it is text.
    cmds = b"t,d1,d2,d3,d4\n0,50,50,0,0\n1,0,5,0,20,0\n2,0,0,0,0\n"
    refused(make_run(tmp_path, commands=cmds), r"commands.csv: not a readable CSV \(.*Expected 5 fields in line 3, saw 6\)$")
    cmds = b't,d1,d2,d3,d4\n0,50,50,0,0\n1,"0,5",0,20,0\n2,0,0,0,0\n'
    refused(make_run(tmp_path, commands=cmds), r"commands.csv: line 3: column d1 is not a finite number \('0,5'\)$")


@pytest.mark.parametrize("sep, name", [(b";", "semicolons"), (b"\t", "tabs")])
def test_other_separators_are_refused_with_a_hint(tmp_path, sep, name):
    # Excel writes the locale's list separator, a semicolon where the decimal mark is a
    # comma (dev-toolbox.tech excel-csv-export: "in Germany, France ... it is a semicolon");
    # "Unicode Text" is tab-separated
    cmds = TIDY_COMMANDS.replace(b",", sep)
    msg = refused(make_run(tmp_path, commands=cmds), "commands.csv: missing column")
    assert f"separated by {name}, the format uses commas" in msg


def test_utf16_is_refused_in_one_line(tmp_path):
    # Excel "Unicode Text" is UTF-16LE with a BOM (wiki.scn.sap.com "Excel files - CSV
    # format": FF FE). Was: "not a readable CSV ('utf-8' codec can't decode byte 0xff ...)".
    cmds = TIDY_COMMANDS.decode().replace(",", "\t").encode("utf-16")
    refused(make_run(tmp_path, commands=cmds), r"commands.csv: UTF-16 text .*save it as 'CSV UTF-8'")


def test_cli_refusal_is_one_line_exit_2(tpods_exe, tmp_path):
    p = make_run(tmp_path, commands=b"t,d1,d2,d3,d4\r\n0,50,50,0,0\r\n\r\n1,20,0,x,0\r\n2,0,0,0,0\r\n")
    r = run_in_process("estimate", "batch", str(p))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"tpods: error: {p / 'commands.csv'}: line 4: column d3 is not a finite number ('x')"]


# ================================================================ thrust tables
TABLE = ('unit = "gf"\nduty_range = [10.0, 90.0]\npressure_psi = 60.0\n[nozzles.1]\n'
         'coefficients = [-9.0692, 1.0439, -0.0128, 7.88e-5]\n')


def load(tmp_path, data: bytes) -> ThrustTable:
    p = tmp_path / "table.toml"
    p.write_bytes(data)
    return ThrustTable.load(p)


def refused_table(tmp_path, data: bytes, match: str) -> str:
    with pytest.raises(UserError, match=match) as ei:
        load(tmp_path, data)
    msg = str(ei.value)
    assert "\n" not in msg and str(tmp_path / "table.toml") in msg
    return msg


@pytest.mark.parametrize("name, text", [
    # TOML integers where floats are meant: TOML 1.0 keeps 10 and 10.0 apart as types;
    # both are numbers here
    ("integers", b'unit = "gf"\nduty_range = [10, 90]\npressure_psi = 60\n[nozzles.1]\n'
                 b'coefficients = [-9.0692, 1.0439, -0.0128, 7.88e-5]\n'),
    ("crlf", TABLE.replace("\n", "\r\n").encode()),   # TOML allows CRLF newlines
    # Notepad / PowerShell write a BOM; tomllib: "Invalid statement (at line 1, column 1)"
    # (python/cpython#157201, hukkin/tomli#304, Nayjest/lm-proxy#79; toml-rs and BurntSushi/toml
    # accept it, toml-rs/toml-rs#75). Was refused.
    ("utf8 bom + crlf", b"\xef\xbb\xbf" + TABLE.replace("\n", "\r\n").encode()),
    ("trailing blank lines", (TABLE + "\n\n\n").encode()),
    ("comments and spacing", (b'# hand-written 2024-05-02, 60 psi\nunit="gf"\nduty_range=[ 10.0 , 90.0 ]\n'
                              b'pressure_psi=60.0   # regulator\n\n[nozzles.1]   # one valve open\n'
                              b'coefficients = [\n  -9.0692,\n  1.0439,\n  -0.0128,\n  7.88e-5,\n]\n')),
    ("inline table", b'unit = "gf"\nduty_range = [10.0, 90.0]\npressure_psi = 60.0\n'
                     b'nozzles = { 1 = { coefficients = [-9.0692, 1.0439, -0.0128, 7.88e-5] } }\n'),
    ("quoted key", TABLE.replace("[nozzles.1]", '[nozzles."1"]').encode()),
    ("exponent forms", TABLE.replace("7.88e-5", "7.88E-05").replace("1.0439", "+1.0439").encode()),
])
def test_hand_written_tables_read_as_the_tidy_one(tmp_path, name, text):
    t = load(tmp_path, text)
    assert t.coefficients == {1: (-9.0692, 1.0439, -0.0128, 7.88e-5)}
    assert (t.unit, t.duty_range, t.pressure_psi) == ("gf", (10.0, 90.0), 60.0)


@pytest.mark.parametrize("text, match", [
    # no unit: was read as gram-force without a word; a table in newtons is then 102x off
    (TABLE.replace('unit = "gf"\n', "").encode(), r'no unit: add unit = "gf" \(gram-force\) or unit = "N"'),
    # true is not a number: was read as 1.0
    (TABLE.replace("pressure_psi = 60.0", "pressure_psi = true").encode(), "True is not a number"),
    (TABLE.replace("7.88e-5]", "true]").encode(), "True is not a number"),
    # [[nozzles]] (an array of tables): was an AttributeError traceback
    (b'unit = "gf"\n[[nozzles]]\ncoefficients = [1.0, 2.0]\n', r"nozzles must be tables \[nozzles.1\]"),
    # errors found by the table's own checks now name the file (they did not)
    (TABLE.replace('"gf"', '"g"').encode(), "unit must be 'gf' or 'N', not 'g'"),
    (TABLE.replace("[nozzles.1]", "[nozzles.0]").encode(), "nozzle count must be a positive integer"),
    (TABLE.replace("7.88e-5", "nan").encode(), r"\[nozzles.1\] coefficients must be finite"),
    # TOML has no leading-dot floats: tomllib's message carries line and column
    (TABLE.replace("-0.0128", "-.0128").encode(), r"not valid TOML \(Invalid value \(at line 5, column"),
    # Notepad's "ANSI" (Windows-1252) degree sign in a comment: was a UnicodeDecodeError traceback
    (("# 60 psi at 20 °C\n" + TABLE).encode("cp1252"), r"line 1: byte 0xb0 is not UTF-8"),
    # UTF-16 (Notepad "Unicode", Windows PowerShell 5 `>`): was a UnicodeDecodeError traceback
    (TABLE.encode("utf-16"), "UTF-16 text; TOML must be UTF-8"),
])
def test_bad_tables_are_one_line_naming_the_file(tmp_path, text, match):
    refused_table(tmp_path, text, match)


def test_a_folder_given_as_table_is_one_line(tmp_path):
    with pytest.raises(UserError, match="cannot read the thrust table"):
        ThrustTable.load(tmp_path)


def test_cli_bad_table_is_one_line_exit_2(tpods_exe, tmp_path):
    table = tmp_path / "table.toml"
    table.write_bytes(("# 20 °C\n" + TABLE).encode("cp1252"))
    p = make_run(tmp_path)
    r = run_in_process("estimate", "batch", str(p), "--thrust-table", str(table))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"tpods: error: {table}: line 1: byte 0xb0 is not UTF-8 (TOML must be UTF-8; save it as UTF-8)"]
