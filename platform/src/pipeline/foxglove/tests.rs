use super::*;

#[test]
fn addresses_parse_to_loopback_unless_given() {
    let o = FoxgloveOptions::parse("8765").expect("a port");
    assert_eq!((o.host.as_str(), o.port), ("127.0.0.1", 8765));
    let o = FoxgloveOptions::parse("0.0.0.0:9000").expect("host and port");
    assert_eq!((o.host.as_str(), o.port), ("0.0.0.0", 9000));
    let o = FoxgloveOptions::parse("[::1]:9001").expect("IPv6");
    assert_eq!((o.host.as_str(), o.port), ("::1", 9001));
    for bad in ["", "x", ":80", "host:", "host:70000"] {
        assert!(FoxgloveOptions::parse(bad).is_err(), "{bad:?} accepted");
    }
}

#[test]
fn timestamps_saturate() {
    assert_eq!(timestamp(-5), Timestamp::new(0, 0));
    assert_eq!(timestamp(1_500_000_001), Timestamp::new(1, 500_000_001));
    assert_eq!(timestamp(i64::MAX), Timestamp::MAX);
}
