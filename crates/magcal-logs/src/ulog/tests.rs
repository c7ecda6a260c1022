use super::*;

#[test]
fn rotations_are_proper_and_match_px4s_names() {
    for (k, _) in ROTATIONS.iter().enumerate() {
        let m = rotation_matrix(k as i64).unwrap();
        let mtm = mat_mul(&m, &[0, 1, 2].map(|i| [0, 1, 2].map(|j| m[j][i])));
        for (i, row) in mtm.iter().enumerate() {
            for (j, x) in row.iter().enumerate() {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((x - want).abs() < 8.0 * f64::EPSILON, "rotation {k}: M M^T = {mtm:?}");
            }
        }
    }
    // ROTATION_YAW_90: the sensor's x axis points along the body's y (right).
    let m = rotation_matrix(2).unwrap();
    let x = [m[0][0], m[1][0], m[2][0]];
    assert!(
        (x[0]).abs() < 1e-15 && (x[1] - 1.0).abs() < 1e-15 && x[2].abs() < 1e-15,
        "{x:?}"
    );
    // ROTATION_ROLL_180: y and z flip.
    let m = rotation_matrix(8).unwrap();
    assert!((m[1][1] + 1.0).abs() < 1e-15 && (m[2][2] + 1.0).abs() < 1e-15);
    assert!(rotation_matrix(48).is_none() && rotation_matrix(-1).is_none());
}

#[test]
fn what_is_kept_is_charged_against_the_memory_budget() {
    fn msg(out: &mut Vec<u8>, kind: u8, body: &[u8]) {
        out.extend_from_slice(&(body.len() as u16).to_le_bytes());
        out.push(kind);
        out.extend_from_slice(body);
    }
    let mut log = b"ULog\x01\x12\x35\x01".to_vec();
    log.extend_from_slice(&0u64.to_le_bytes());
    msg(
        &mut log,
        b'F',
        b"sensor_mag:uint64_t timestamp;float x;float y;float z;",
    );
    msg(&mut log, b'A', b"\x00\x00\x00sensor_mag");
    for t in 0..1000u64 {
        let mut d = vec![0, 0];
        d.extend_from_slice(&t.to_le_bytes());
        d.extend_from_slice(&[0; 12]);
        msg(&mut log, b'D', &d);
    }
    let budget = |limit| Budget {
        used: 0,
        limit: Some((limit, 2 * limit, "a test's limit")),
    };
    let raw = parse(&mut log.as_slice(), "t.ulg", budget(1 << 30)).unwrap();
    assert_eq!(raw.sensor_mag[&0].len(), 1000);
    // 100 readings fit in 100 * HELD_PER_READING bytes and a little; the 101st does not.
    let limit = 100 * HELD_PER_READING + HELD_PER_ENTRY * 6 + 64;
    let e = parse(&mut log.as_slice(), "t.ulg", budget(limit))
        .unwrap_err()
        .to_string();
    let at = 16 + 3 + 54 + 3 + 13 + 100 * 25;
    assert!(
        e.starts_with(&format!("t.ulg: byte {at}: the log holds more than fits in memory")),
        "{e}"
    );
}

#[test]
fn versions_read_as_px4_writes_them() {
    assert_eq!(version_words(0x011001C0), "v1.16.1 (release candidate)");
    assert_eq!(version_words(0x010B0200), "v1.11.2 (development)");
    assert_eq!(version_words(0x010C03FF), "v1.12.3 (release)");
}

#[test]
fn formats_parse_and_nest() {
    let (name, fields) = parse_format("a:uint64_t timestamp;b[2] bs;float[3] v;uint8_t[4] _padding0;").unwrap();
    assert_eq!(name, "a");
    assert_eq!(fields.len(), 4);
    let mut formats = HashMap::new();
    formats.insert(name, fields);
    formats.insert("b".to_string(), parse_format("b:uint16_t u;double d;").unwrap().1);
    let mut sizes = HashMap::new();
    let at = locate("a", "v", "float", &formats, &mut sizes).unwrap().unwrap();
    assert_eq!((at.offset, at.count), (8 + 2 * 10, 3));
    assert!(locate("a", "v", "double", &formats, &mut sizes).is_err());
    // A format that contains itself stops at the nesting bound.
    formats.insert("c".to_string(), parse_format("c:c self;float x;").unwrap().1);
    let e = locate("c", "x", "float", &formats, &mut sizes).unwrap_err();
    assert!(e.contains("nested deeper than 16"), "{e}");
    for bad in ["nocolon", ":float x;", "a:float;", "a:float[x] y;", "a:float[70000] y;"] {
        assert!(parse_format(bad).is_err(), "{bad}");
    }
}
