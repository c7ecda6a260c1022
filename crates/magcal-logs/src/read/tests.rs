use super::*;

/// A line without quotes splits into csv-core's cells: random lines of separators, spaces,
/// digits, letters, tabs and multi-byte characters, for each separator.
#[test]
fn lines_without_quotes_split_as_csv_core_splits_them() {
    use rand::RngExt;
    let alphabet: [&[u8]; 11] = [
        b",",
        b";",
        b"\t",
        b" ",
        b"1",
        b".",
        b"-",
        b"e",
        b"x",
        "\u{e9}".as_bytes(),
        b",",
    ];
    let mut rng = magcal_core::rng::stream_rng(35, 0);
    for d in [b',', b';', b'\t'] {
        let mut splitter = Splitter::new(Separator::Byte(d));
        for _ in 0..5_000 {
            let mut line = Vec::new();
            for _ in 0..rng.random_range(1..40) {
                line.extend_from_slice(alphabet[rng.random_range(0..alphabet.len())]);
            }
            line.push(b'\n');
            let mut reader = csv_core::ReaderBuilder::new().delimiter(d).build();
            let (mut out, mut ends) = (vec![0; line.len()], vec![0; line.len() + 1]);
            let (result, _, _, count) = reader.read_record(&line, &mut out, &mut ends);
            assert_eq!(result, csv_core::ReadRecordResult::Record);
            let expected: Vec<&[u8]> = (0..count)
                .map(|i| out[if i == 0 { 0 } else { ends[i - 1] }..ends[i]].trim_ascii())
                .collect();
            splitter.split(&line).unwrap();
            let got: Vec<&[u8]> = (0..splitter.len()).map(|i| splitter.get(i).unwrap()).collect();
            assert_eq!(got, expected, "{:?}", String::from_utf8_lossy(&line));
        }
    }
}

fn parse(text: &[u8], columns: Option<&str>, skip_bad: bool) -> Result<(Vec<(usize, Vec3)>, Streamed)> {
    let mut rows = Vec::new();
    let budget = Budget { held: 32, limit: None };
    let s = read_from(
        BufReader::new(text),
        "t.csv",
        Wanted {
            columns,
            extras: &[],
            filters: &[],
            skip_bad,
        },
        &budget,
        &mut |l, r, _| {
            rows.push((l, r));
            Ok(())
        },
    )?;
    Ok((rows, s))
}

fn error(text: &[u8], columns: Option<&str>) -> String {
    format!("{:#}", parse(text, columns, false).unwrap_err())
}

/// The lines `filters` keep of `text`, and the rows they left out; or the error.
fn filtered(text: &[u8], filters: &[&str]) -> Result<(Vec<usize>, usize)> {
    let filters: Vec<RowFilter> = filters.iter().map(|f| RowFilter::parse(f).unwrap()).collect();
    let mut lines = Vec::new();
    let wanted = Wanted {
        columns: None,
        extras: &[],
        filters: &filters,
        skip_bad: true,
    };
    let budget = Budget { held: 32, limit: None };
    let s = read_from(BufReader::new(text), "t.csv", wanted, &budget, &mut |l, _, _| {
        lines.push(l);
        Ok(())
    })?;
    Ok((lines, s.filtered))
}

#[test]
fn rows_are_kept_where_every_filter_holds_and_the_rest_counted() {
    let text = b"x,y,z,movement,phase\n1,2,3,1,a\n1,2,3,0,a\n1,2,3,1.0,b\n1,2,3,,a\n1,,3,1,a\n";
    // Numbers compare as numbers (1.0 is 1); an empty cell meets no number. Line 6 meets the
    // filter and is skipped for its missing y (skip_bad), not counted as left out.
    assert_eq!(filtered(text, &["movement=1"]).unwrap(), (vec![2, 4], 2));
    // Filters combine; by index; text compares as text, case kept.
    assert_eq!(filtered(text, &["4=1", "phase=a"]).unwrap(), (vec![2], 3));
    assert_eq!(
        filtered(text, &["phase=A"]).unwrap_err().to_string(),
        "t.csv: no row meets --where phase=A (5 rows)"
    );
    // A filter's column may be one of the field's.
    assert_eq!(filtered(text, &["x=1"]).unwrap(), (vec![2, 3, 4, 5], 0));
    for (filter, want) in [
        (
            "moved=1",
            "t.csv: --where \"moved\": no column of that name (columns: x, y, z, movement, phase)",
        ),
        ("9=1", "t.csv: --where \"9\": column 9 is not in the log (5 columns)"),
        (
            "phase=1",
            "t.csv: line 2, column 5 (phase): \"a\" is not a number, and --where phase=1 compares numbers",
        ),
    ] {
        assert_eq!(format!("{:#}", filtered(text, &[filter]).unwrap_err()), want);
    }
    for bad in ["movement", "=1", "movement=", " = "] {
        assert!(
            RowFilter::parse(bad).unwrap_err().contains("give COLUMN=VALUE"),
            "{bad}"
        );
    }
    assert_eq!(
        RowFilter::parse(" movement = 1=2 ").unwrap(),
        RowFilter {
            column: "movement".into(),
            value: "1=2".into()
        }
    );
}

#[test]
fn extra_columns_are_read_by_name_or_index_and_empty_cells_are_none() {
    let text = b"t,mx,my,mz,qw\n0.5,1,2,3,1\n1.0,4,5,6,\n1.5,7,8,9,nan\n";
    let mut rows = Vec::new();
    let extras = [
        Extra {
            flag: "--time",
            column: "T",
        },
        Extra {
            flag: "--quaternion",
            column: "5",
        },
    ];
    let wanted = Wanted {
        columns: None,
        extras: &extras,
        filters: &[],
        skip_bad: false,
    };
    let budget = Budget { held: 32, limit: None };
    read_from(BufReader::new(&text[..]), "t.csv", wanted, &budget, &mut |l, r, e| {
        rows.push((l, r, e.to_vec()));
        Ok(())
    })
    .unwrap();
    assert_eq!(
        rows,
        [
            (2, [1.0, 2.0, 3.0], vec![Some(0.5), Some(1.0)]),
            (3, [4.0, 5.0, 6.0], vec![Some(1.0), None]),
            (4, [7.0, 8.0, 9.0], vec![Some(1.5), None]),
        ]
    );
    for (column, want) in [
        ("mx", "--time \"mx\": column 2 (mx) is one of the field's columns"),
        ("9", "--time \"9\": column 9 is not in the log (5 columns)"),
        (
            "when",
            "--time \"when\": no column of that name (columns: t, mx, my, mz, qw)",
        ),
    ] {
        let extras = [Extra { flag: "--time", column }];
        let wanted = Wanted {
            extras: &extras,
            ..wanted
        };
        let e = read_from(BufReader::new(&text[..]), "t.csv", wanted, &budget, &mut |_, _, _| {
            Ok(())
        })
        .unwrap_err();
        assert!(format!("{e:#}").contains(want), "{e:#}");
    }
    let bad = b"t,x,y,z\n0.5,1,2,3\nsoon,1,2,3\n";
    let extras = [Extra {
        flag: "--time",
        column: "t",
    }];
    let wanted = Wanted {
        extras: &extras,
        ..wanted
    };
    let e = read_from(
        BufReader::new(&bad[..]),
        "t.csv",
        wanted,
        &budget,
        &mut |_, _, _| Ok(()),
    )
    .unwrap_err();
    assert!(
        format!("{e:#}").contains("t.csv: line 3, column 1 (t): \"soon\" is not a number"),
        "{e:#}"
    );
}

#[test]
fn line_numbers_count_every_terminator() {
    // Two blank lines, then the bad row on line 6.
    let e = error(b"x,y,z\n1,2,3\n2,3,4\n\n\nnan,1,2\n", None);
    assert!(e.contains("line 6: column 1 (x) is NaN"), "{e}");
    // CR-only, CRLF and a mix: the same lines.
    for text in [
        &b"x,y,z\r1,2,3\r\r2,3,nan\r"[..],
        b"x,y,z\r\n1,2,3\r\n\r\n2,3,nan\r\n",
        b"x,y,z\n1,2,3\r\n\r2,3,nan",
    ] {
        let e = error(text, None);
        assert!(e.contains("line 4: column 3 (z) is NaN"), "{e}");
    }
    let (rows, _) = parse(b"# c\n\nx,y,z\n1,2,3\n\n2,3,4\r\n5,6,7", None, false).unwrap();
    assert_eq!(rows, [(4, [1.0, 2.0, 3.0]), (6, [2.0, 3.0, 4.0]), (7, [5.0, 6.0, 7.0])]);
}

#[test]
fn a_crlf_split_across_reads_is_one_terminator() {
    // A buffer of one byte splits every `\r\n`.
    let text = b"x,y,z\r\n1,2,3\r\n4,5,6\r\n";
    let mut lines = Lines::new(BufReader::with_capacity(1, &text[..]));
    let mut buf = Vec::new();
    let mut got = Vec::new();
    while let Some(n) = lines.next(&mut buf, "t").unwrap() {
        got.push((n, String::from_utf8(buf.clone()).unwrap()));
    }
    assert_eq!(got, [(1, "x,y,z".into()), (2, "1,2,3".into()), (3, "4,5,6".into())]);
}

#[test]
fn separators_are_sniffed_and_decimal_commas_read_where_unambiguous() {
    let want = [[1.5, -2.25, 3.0], [4.0, 5.0, 6.0]];
    for text in [
        &b"x;y;z\n1,5;-2,25;3\n4;5;6\n"[..],
        b"x\ty\tz\n1.5\t-2.25\t3\n4\t5\t6\n",
        b"x y  z\n 1,5  -2,25 3\n4 5 6\n",
        b"\xef\xbb\xbf\"x\",\"y\",\"z\"\n\"1.5\",-2.25,3\n4,5,6\n",
    ] {
        let (rows, s) = parse(text, None, false).unwrap();
        let got: Vec<Vec3> = rows.iter().map(|r| r.1).collect();
        assert_eq!(got, want, "{}", String::from_utf8_lossy(text));
        assert_eq!(s.columns, ["x", "y", "z"]);
    }
    // A decimal comma in a comma-separated log is named.
    let e = error(b"x,y,z\n\"1,5\",2,3\n", None);
    assert!(e.contains("\"1,5\" is not a number (a decimal comma"), "{e}");
}

#[test]
fn columns_chosen_twice_or_ambiguous_are_refused() {
    let e = error(b"x,y,z\n1,2,3\n", Some("1,1,1"));
    assert!(e.contains("column 1 (x) is chosen twice"), "{e}");
    let e = error(b"x,y,z\n1,2,3\n", Some("x,Y,x"));
    assert!(e.contains("column 1 (x) is chosen twice"), "{e}");
    let e = error(b"x,y,z,x,y,z\n1,2,3,4,5,6\n", None);
    assert!(e.contains("columns 1, 4 are all named \"x\""), "{e}");
    let e = error(b"a,b,a\n1,2,3\n", Some("a,b,3"));
    assert!(e.contains("columns 1 and 3 are both named \"a\""), "{e}");
    let (rows, _) = parse(b"x,y,z,x,y,z\n1,2,3,4,5,6\n", Some("4,5,6"), false).unwrap();
    assert_eq!(rows, [(2, [4.0, 5.0, 6.0])]);
}

#[test]
fn errors_quote_a_short_excerpt() {
    let long = format!("x,y,z\n1,2,{}\n", "a".repeat(10_000));
    let e = error(long.as_bytes(), None);
    assert!(e.len() < 200 && e.contains("line 2, column 3 (z)"), "{e}");
    let open = format!("x,y,z\n1,2,\"3{}\n4,5,6\n", "b".repeat(10_000));
    let e = error(open.as_bytes(), None);
    assert!(e.len() < 200 && e.contains("line 2: a quote"), "{e}");
    let huge = vec![b'0'; MAX_LINE_BYTES + 1];
    let e = error(&huge, None);
    assert!(e.len() < 200 && e.contains("line 1 is longer than 1.0 MiB"), "{e}");
    // Exactly the limit is a line.
    let mut at = b"x,y,z\n1,2,3".to_vec();
    at.extend(std::iter::repeat_n(b' ', MAX_LINE_BYTES - 5));
    assert_eq!(parse(&at, None, false).unwrap().0.len(), 1);
}

#[test]
fn skipped_rows_are_counted_and_the_budget_bounds_the_rows() {
    let (rows, s) = parse(b"x,y,z\n1,2,3\n1,,3\ninf,1,1\n4,5,6\n", None, true).unwrap();
    assert_eq!(rows.len(), 2);
    assert_eq!(s.skipped.iter().map(|s| s.0).collect::<Vec<_>>(), [3, 4]);
    // A budget of two readings at 32 B stops at the third, naming its line.
    let budget = Budget {
        held: 32,
        limit: Some((64, 128, "test")),
    };
    let e = read_from(
        BufReader::new(&b"x,y,z\n1,2,3\n\n4,5,6\n7,8,9\n"[..]),
        "t.csv",
        Wanted {
            columns: None,
            extras: &[],
            filters: &[],
            skip_bad: false,
        },
        &budget,
        &mut |_, _, _| Ok(()),
    )
    .unwrap_err();
    assert!(
        format!("{e:#}").contains("t.csv: line 5: the log holds more rows than fit"),
        "{e:#}"
    );
}

#[test]
fn empty_and_header_only_logs_are_named() {
    assert!(error(b"\n# only a comment\n\n", None).contains("the log is empty"));
    assert!(error(b"x,y,z\n\n", None).contains("has a header but no readings"));
    let e = error(b"x y\n1 2\n", None);
    assert!(
        e.contains("read as space-separated") && e.contains("fewer than three"),
        "{e}"
    );
}

fn columns(text: &[u8], asked: Option<&str>) -> [String; 3] {
    parse(text, asked, false).unwrap().1.columns
}

#[test]
fn the_default_columns_are_x_y_z_with_a_prefix_in_any_case_else_the_first_three_numeric() {
    // Prefixes `m`, `mag`, `mag_`, any case, behind a time and an accelerometer; the order of
    // the axes is the names', not the file's.
    for (header, want, value) in [
        ("t,ax,ay,az,mx,my,mz", ["mx", "my", "mz"], [1.0, 2.0, 3.0]),
        (
            "t,ax,ay,az,MAG_X,Mag_Y,mag_z",
            ["MAG_X", "Mag_Y", "mag_z"],
            [1.0, 2.0, 3.0],
        ),
        ("t,ax,ay,az,magx,magy,magz", ["magx", "magy", "magz"], [1.0, 2.0, 3.0]),
        ("t,ax,ay,az,Z,Y,X", ["X", "Y", "Z"], [3.0, 2.0, 1.0]),
    ] {
        let text = format!("{header}\n0.5,9,8,7,1,2,3\n");
        let (rows, s) = parse(text.as_bytes(), None, false).unwrap();
        assert_eq!(s.columns, want, "{header}");
        assert_eq!(rows, [(2, value)], "{header}");
    }
    // Plain `x, y, z` come before a prefixed set.
    assert_eq!(columns(b"mx,my,mz,x,y,z\n1,2,3,4,5,6\n", None), ["x", "y", "z"]);
    // No such names: the first three columns whose first data row is numeric.
    let (rows, s) = parse(b"time,a,b,c,d\n12:00:01,1,2,3,4\n12:00:02,5,6,7,8\n", None, false).unwrap();
    assert_eq!(s.columns, ["a", "b", "c"]);
    assert_eq!(rows, [(2, [1.0, 2.0, 3.0]), (3, [5.0, 6.0, 7.0])]);
    // Without a header, columns are named by their 1-based index; comments (indented too)
    // do not set the separator.
    let (rows, s) = parse(b"# a; b\n  # c,d\n7 1 2 3\n", None, false).unwrap();
    assert_eq!(s.columns, ["column 1", "column 2", "column 3"]);
    assert_eq!(rows, [(3, [7.0, 1.0, 2.0])]);
    // An empty name is its index.
    assert_eq!(columns(b"x,,z,w\n1,2,3,4\n", Some("1,2,4")), ["x", "column 2", "w"]);
}

#[test]
fn asked_columns_by_name_in_any_case_or_by_index_and_their_errors() {
    let text = b"t,mx,my,mz,mz\n0,1,2,3,4\n";
    // A name two columns carry is recorded by index, so that the record finds it again.
    let (rows, s) = parse(text, Some(" MX, My ,4"), false).unwrap();
    assert_eq!(s.columns, ["mx", "my", "column 4"]);
    assert_eq!(rows, [(2, [1.0, 2.0, 3.0])]);
    assert_eq!(columns(text, Some("2,3,5")), ["mx", "my", "column 5"]);
    let prefix = "t.csv (read as comma-separated): ";
    for (asked, message) in [
        (
            Some("mx,my"),
            "--columns \"mx,my\": give three columns, names or 1-based indices",
        ),
        (
            Some("1,2,9"),
            "--columns \"1,2,9\": column 9 is not in the log (5 columns)",
        ),
        (
            Some("0,1,2"),
            "--columns \"0,1,2\": column 0 is not in the log (5 columns)",
        ),
        (
            Some("mx,my,q"),
            "--columns \"mx,my,q\": no column named \"q\" (columns: t, mx, my, mz, mz)",
        ),
        (
            Some("mx,my,mz"),
            "--columns \"mx,my,mz\": columns 4 and 5 are both named \"mz\"; give indices",
        ),
        (
            None,
            "columns 4, 5 are all named \"mz\"; choose with --columns (columns: t, mx, my, mz, mz)",
        ),
    ] {
        assert_eq!(error(text, asked), format!("{prefix}{message}"));
    }
}

#[test]
fn column_lists_in_errors_are_short_and_escape_control_characters() {
    // A name with an escape sequence is shown escaped, never sent to the terminal.
    let e = error(b"\x1b[2Jx,y,z\n1,2,3\n", Some("q,y,z"));
    assert!(!e.contains('\x1b'), "{e:?}");
    assert!(e.ends_with("no column named \"q\" (columns: \\u{1b}[2Jx, y, z)"), "{e}");
    // At most 12 names, each cut at 24 characters.
    let names: Vec<String> = (1..=30).map(|i| format!("{i}{}", "n".repeat(40))).collect();
    let text = format!("{}\n{}\n", names.join(","), vec!["1"; 30].join(","));
    let e = error(text.as_bytes(), Some("a,b,c"));
    let listed: Vec<String> = names[..12].iter().map(|n| format!("{}...", &n[..24])).collect();
    assert_eq!(
        e.split_once("(columns: ").unwrap().1,
        format!("{}, ... (30 columns))", listed.join(", "))
    );
    // The asked text itself is an excerpt.
    let asked = "q".repeat(1000);
    let e = error(b"x,y,z\n1,2,3\n", Some(&asked));
    assert!(
        e.len() < 200 && e.contains(&format!("{:?}...", "q".repeat(EXCERPT_CHARS))),
        "{e}"
    );
}

#[test]
fn a_bad_cell_is_named_by_line_column_and_value() {
    assert_eq!(
        error(b"x,y,z\n1,2,3\n4,abc,6\n", None),
        "t.csv: line 3, column 2 (y): \"abc\" is not a number"
    );
    let skip = " (--skip-bad drops such rows and counts them)";
    for (text, reason) in [
        (&b"x,y,z\n1,2\n"[..], "line 2: no value in column 3 (z)"),
        (b"x,y,z\n1,,3\n", "line 2: no value in column 2 (y)"),
        (b"x,y,z\n-inf,2,3\n", "line 2: column 1 (x) is -inf"),
        (
            b"x,y,z\n1,2,1e999\n",
            "line 2: column 3 (z) is \"1e999\", beyond the largest number (1.8e308)",
        ),
        (b"x,y,z\n1,2,-inf\n", "line 2: column 3 (z) is -inf"),
    ] {
        assert_eq!(error(text, None), format!("t.csv: {reason}{skip}"));
    }
    // Skipped, each with its line and reason; the other rows read.
    let (rows, s) = parse(b"x,y,z\n1,2\n4,5,6\n\n1,,3\n", None, true).unwrap();
    assert_eq!(rows, [(3, [4.0, 5.0, 6.0])]);
    assert_eq!(
        s.skipped,
        [
            (2, "no value in column 3 (z)".to_string()),
            (5, "no value in column 2 (y)".to_string())
        ]
    );
    // A text cell is an error even with skip_bad: it is not a missing value.
    assert!(format!("{:#}", parse(b"x,y,z\n1,2,q\n", None, true).unwrap_err()).contains("\"q\" is not a number"));
    // Every row skipped is no log.
    assert_eq!(
        format!("{:#}", parse(b"x,y,z\n1,2\n", None, true).unwrap_err()),
        "t.csv: no readings (1 rows skipped)"
    );
}

#[test]
fn utf16_and_binary_files_are_named_as_such() {
    assert_eq!(
        error(b"\xff\xfex\x00,\x00y\x00", None),
        "t.csv: line 1: the log is UTF-16 text (it starts with a UTF-16 byte order mark); save it as UTF-8"
    );
    assert_eq!(
        error(b"x,y,z\n1,2\x003\n", None),
        "t.csv: line 2: byte 4 is NUL: not a text log (UTF-16 text or a binary file? a flight log through a pipe: give --format)"
    );
}

#[test]
fn excerpts_are_cut_at_a_character_count_and_say_so() {
    assert_eq!(excerpt(b"abc"), "\"abc\"");
    let long = "\u{e9}".repeat(100);
    assert_eq!(
        excerpt(long.as_bytes()),
        format!("{:?}...", "\u{e9}".repeat(EXCERPT_CHARS))
    );
    let exact = "a".repeat(EXCERPT_CHARS);
    assert_eq!(excerpt(exact.as_bytes()), format!("{exact:?}"));
    // Bytes that are not UTF-8 are shown replaced, still quoted.
    assert_eq!(excerpt(b"\xff1"), "\"\u{fffd}1\"");
}

/// The readings of `path` with their lines, and what the stream says.
#[derive(Debug)]
struct Held {
    readings: Vec<Vec3>,
    lines: Vec<usize>,
    columns: [String; 3],
    sha256: String,
    bytes: u64,
}

fn read(path: &Path, columns: Option<&str>, skip_bad: bool) -> Result<Held> {
    let (mut readings, mut lines) = (Vec::new(), Vec::new());
    let s = stream(path, columns, skip_bad, 32, |line, r| {
        readings.push(r);
        lines.push(line);
        Ok(())
    })?;
    Ok(Held {
        readings,
        lines,
        columns: s.columns,
        sha256: s.sha256,
        bytes: s.bytes,
    })
}

#[test]
fn a_file_is_read_with_its_hash_and_size_and_a_directory_or_missing_file_is_named() {
    use sha2::{Digest, Sha256};
    let dir = tempfile::TempDir::new().unwrap();
    let path = dir.path().join("log.csv");
    let bytes = b"\xef\xbb\xbf# log\nmx;my;mz\n1,5;2;3\n\n4;5;6,25\n";
    std::fs::write(&path, bytes).unwrap();
    let log = read(&path, None, false).unwrap();
    assert_eq!(log.readings, [[1.5, 2.0, 3.0], [4.0, 5.0, 6.25]]);
    assert_eq!(log.lines, [3, 5]);
    assert_eq!(log.columns, ["mx", "my", "mz"]);
    assert_eq!(log.bytes, bytes.len() as u64);
    let hex: String = Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect();
    assert_eq!(log.sha256, hex);
    // The first row as the calibration check sees it: the same header.
    assert_eq!(
        first_row(&path),
        Some((true, vec!["mx".to_string(), "my".into(), "mz".into()]))
    );
    let e = format!("{:#}", read(dir.path(), None, false).unwrap_err());
    assert_eq!(e, format!("{}: is a directory, not a log", dir.path().display()));
    let missing = dir.path().join("missing.csv");
    let e = format!("{:#}", read(&missing, None, false).unwrap_err());
    assert!(
        e.starts_with(&format!("{}: cannot read the log: ", missing.display())),
        "{e}"
    );
    // An error of the caller's is returned as it is, after the rows before it.
    let mut seen = Vec::new();
    let e = stream(&path, None, false, 0, |line, _| {
        seen.push(line);
        if line == 5 {
            bail!("stop at line {line}")
        } else {
            Ok(())
        }
    })
    .unwrap_err();
    assert_eq!((format!("{e:#}"), seen), ("stop at line 5".to_string(), vec![3, 5]));
}

#[test]
fn the_first_row_is_a_header_only_with_a_cell_that_is_not_a_number() {
    let dir = tempfile::TempDir::new().unwrap();
    let at = |name: &str, bytes: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        first_row(&p)
    };
    let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    assert_eq!(at("a", b"\n# c\n1\t2\t3\n"), Some((false, names(&["1", "2", "3"]))));
    assert_eq!(at("b", b"x,,z\n1,2,3\n"), Some((true, names(&["x", "column 2", "z"]))));
    // A decimal comma is a number where the separator allows it.
    assert_eq!(at("c", b"1,5;2;3\n"), Some((false, names(&["1,5", "2", "3"]))));
    assert_eq!(at("d", b"# only\n\n"), None);
    assert_eq!(at("e", b"x,\x00y,z\n1,2,3\n"), None);
    assert_eq!(first_row(&dir.path().join("missing")), None);
}
