//! `monitor`: the board's non-record lines — `$MCBOOT` banner, `$MCSYN` acknowledgements,
//! `$MCACK,STATUS` counters, `$MCERR,8,STORAGE` — are recognised (not "other lines"),
//! CRC-checked, and the STATUS counters are shown.

use magcomp::board::monitor::{
    checked_body, monitor_stream, parse_boot, parse_status, parse_sync, status_text, BoardStatus,
    Display, Monitor,
};
use magcomp_core::protocol::common::crc16_ccitt;
use magcomp_core::protocol::record::{encode_record, Record, MAX_RECORD_LEN};
use magcomp_core::{Flags, MagCounts};

/// `$<body>*HHHH\r\n` as the firmware writes its sentences.
fn sentence(body: &str) -> Vec<u8> {
    format!("${body}*{:04X}\r\n", crc16_ccitt(body.as_bytes())).into_bytes()
}

fn record(seq: u32) -> Vec<u8> {
    let mag = MagCounts(536_204_401);
    let r = Record {
        seq,
        t_s: seq as f64 * 0.1,
        mag: Some(mag),
        interference_nt: 1.0,
        compensated: Record::compensate(Some(mag), 1.0),
        anomaly_nt: 0.0,
        innovation_nt: 0.0,
        sigma_nt: 0.25,
        flags: Flags::empty(),
    };
    let mut b = [0u8; MAX_RECORD_LEN];
    let n = encode_record(&r, &mut b).unwrap();
    b[..n].to_vec()
}

#[test]
fn board_lines_parse_with_their_crc() {
    let b = parse_boot(&sentence("MCBOOT,emu-f405,0.1.0,SYNC")).unwrap();
    assert_eq!(
        (b.board.as_str(), b.version.as_str(), b.sync),
        ("emu-f405", "0.1.0", true)
    );
    assert!(!parse_boot(&sentence("MCBOOT,acq-f405,0.1.0")).unwrap().sync);
    assert!(parse_boot(&sentence("MCBOOT,acq-f405,0.1.0,XYZ")).is_none());
    assert!(parse_boot(&sentence("MCBOOT,acq-f405")).is_none());
    let b = parse_boot(&sentence(
        "MCBOOT,acq-f405,0.1.0,RST=SW,PANIC=src/fw.rs:565",
    ))
    .unwrap();
    assert_eq!(b.reset_cause.as_deref(), Some("SW"));
    assert_eq!(b.panic.as_deref(), Some("src/fw.rs:565"));
    assert!(!b.sync);
    let b = parse_boot(&sentence("MCBOOT,emu-f405,0.1.0,RST=IWDG,SYNC")).unwrap();
    assert_eq!((b.reset_cause.as_deref(), b.sync), (Some("IWDG"), true));
    assert_eq!(parse_sync(&sentence("MCSYN,12,11,3")), Some([12, 11, 3]));
    assert!(parse_sync(&sentence("MCSYN,12,11")).is_none());
    assert_eq!(
        parse_status(&sentence("MCACK,STATUS,SURVEY,400,52,56,33,1,2")),
        Some(BoardStatus {
            survey: true,
            records: 400,
            err_scalar: 52,
            err_flux: 56,
            err_gps: 33,
            err_uart: 1,
            err_cmd: 2,
            flux_suspect: None,
        })
    );
    assert!(parse_status(&sentence("MCACK,STATUS,FOO,1,2,3,4,5,6")).is_none());
    assert!(parse_status(&sentence("MCACK,STATUS,CAL,1,2,3,4,5")).is_none());
    // the UART breakdown a newer firmware appends (by kind, by port) is accepted
    let s = parse_status(&sentence("MCACK,STATUS,CAL,1,2,3,4,5,6,3,2,0,1,0,4,0")).unwrap();
    assert_eq!((s.err_uart, s.err_cmd), (5, 6));
    assert!(parse_status(&sentence("MCACK,STATUS,CAL,1,2,3,4,5,6,3,2")).is_none());
    // and then the fluxgate frames refused as suspect
    let s = parse_status(&sentence("MCACK,STATUS,CAL,1,2,3,4,5,6,3,2,0,1,0,4,0,12")).unwrap();
    assert_eq!((s.err_cmd, s.flux_suspect), (6, Some(12)));
    assert!(
        status_text(&s).ends_with("| flux suspect 12"),
        "{}",
        status_text(&s)
    );
    // a wrong CRC is not a board line
    let mut bad = sentence("MCSYN,1,2,3");
    bad[3] = b'X';
    assert!(checked_body(&bad).is_none() && parse_sync(&bad).is_none());
    assert_eq!(checked_body(b"$MCERR,8,STORAGE*1234"), None);
    assert_eq!(
        checked_body(&sentence("MCERR,8,STORAGE")),
        Some(&b"MCERR,8,STORAGE"[..])
    );
}

#[test]
fn monitor_counts_board_lines_and_shows_status() {
    let mut s = Vec::new();
    s.extend(sentence("MCBOOT,emu-f405,0.1.0,SYNC"));
    for seq in 0..20 {
        s.extend(sentence(&format!("MCSYN,{},{},0", seq + 1, seq)));
        s.extend(record(seq));
    }
    s.extend(sentence("MCACK,STATUS,CAL,20,1,2,3,0,4"));
    s.extend(sentence("MCERR,8,STORAGE"));
    let mut bad = sentence("MCSYN,9,9,9");
    bad[4] = b'Z'; // CRC fails: an "other" line
    s.extend(bad);
    s.extend(sentence("MCBOOT,emu-f405,0.1.0,SYNC")); // a reset
    let mut out = Vec::new();
    let st = monitor_stream(&s[..], "test", Display::Quiet, false, &mut out, None).unwrap();
    assert_eq!(st.records, 20);
    assert_eq!(st.boots, 2);
    assert_eq!(st.syncs, 20);
    assert_eq!(st.sync, Some([20, 19, 0]));
    assert_eq!(st.replies, 2);
    assert_eq!(st.storage_errors, 1);
    assert_eq!(st.other_lines, 1);
    let status = st.status.unwrap();
    assert_eq!(
        (status.records, status.err_flux, status.err_cmd),
        (20, 2, 4)
    );
    let text = String::from_utf8(out).unwrap();
    assert!(
        text.contains("status CAL records 20 | errors scalar 1 flux 2 gps 3 uart 0 cmd 4"),
        "{text}"
    );
    assert!(
        text.contains("boots 2") && text.contains("storage errors 1"),
        "{text}"
    );

    // the live panel shows the board, its counters and the frames taken
    let mut m = Monitor::new();
    for l in s.split(|&b| b == b'\n') {
        m.push_line(l);
    }
    let p = m.panel("test");
    assert!(
        p.contains("board          emu-f405 0.1.0 SYNC (boots 2)"),
        "{p}"
    );
    assert!(p.contains("board status   CAL records 20"), "{p}");
    assert!(p.contains("frames taken   scalar 20 flux 19 gps 0"), "{p}");
    assert!(p.contains("flash write failures 1"), "{p}");
}
