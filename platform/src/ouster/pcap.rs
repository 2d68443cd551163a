//! UDP datagrams of a pcap capture (libpcap format, as `tcpdump -w` and Ouster's sample data
//! write), IPv4 fragments reassembled.
//!
//! Ouster lidar packets are larger than a 1500-byte MTU, so a capture holds them as IPv4
//! fragments: the first carries the UDP header, the next ones only payload. The records are read
//! by `pcap-file`, the Ethernet / IPv4 / UDP headers parsed and fragments reassembled by
//! `etherparse` (fragments whose datagram never completes within [`FRAGMENT_TIMEOUT_NS`] of
//! capture time are dropped and counted). Link types: Ethernet, raw IP, Linux cooked (SLL).

use crate::IoError;
use etherparse::defrag::IpDefragPool;
use etherparse::{NetSlice, SlicedPacket, TransportSlice, UdpSlice};
use pcap_file::pcap::PcapReader;
use pcap_file::DataLink;
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Capture time after which a datagram's missing fragments are given up, ns.
pub const FRAGMENT_TIMEOUT_NS: i64 = 1_000_000_000;

/// Identifies a fragmented datagram: source and destination addresses, identification.
type FragKey = (Vec<u8>, Vec<u8>, u32);

fn frag_key(net: &NetSlice) -> Option<FragKey> {
    match net {
        NetSlice::Ipv4(ip) => {
            let h = ip.header();
            Some((
                h.source().to_vec(),
                h.destination().to_vec(),
                u32::from(h.identification()),
            ))
        }
        NetSlice::Ipv6(ip) => {
            let h = ip.header();
            let id = ip.extensions().clone().into_iter().find_map(|e| match e {
                etherparse::Ipv6ExtensionSlice::Fragment(f) => Some(f.identification()),
                _ => None,
            })?;
            Some((h.source().to_vec(), h.destination().to_vec(), id))
        }
        _ => None,
    }
}

/// One UDP datagram of a capture.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UdpDatagram {
    /// Capture time of the record that completed it, ns since the Unix epoch.
    pub t_capture_ns: i64,
    /// Source port.
    pub src_port: u16,
    /// Destination port.
    pub dst_port: u16,
    /// The UDP payload.
    pub payload: Vec<u8>,
}

/// What a [`PcapUdp`] read and skipped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PcapCounts {
    /// Capture records read.
    pub records: u64,
    /// UDP datagrams returned.
    pub datagrams: u64,
    /// Records that were IPv4 fragments.
    pub fragments: u64,
    /// Datagrams reassembled from fragments.
    pub reassembled: u64,
    /// Datagrams being reassembled given up (a fragment lost), or fragments that did not fit.
    pub incomplete: u64,
    /// Records that are not UDP (ARP, TCP, ...).
    pub non_udp: u64,
    /// UDP datagrams to other ports than the ones asked for.
    pub other_ports: u64,
    /// Records whose headers do not parse (cut by the snap length, garbage).
    pub malformed: u64,
}

/// Iterator over the UDP datagrams of a pcap capture, in capture order (a fragmented datagram
/// at its last fragment). Items are `Err` for a corrupt capture file, naming the byte offset of
/// the record that failed; iteration stops after an error.
pub struct PcapUdp<R: Read> {
    reader: PcapReader<R>,
    path: PathBuf,
    datalink: DataLink,
    pool: IpDefragPool<i64, ()>,
    /// The datagrams being reassembled (source, destination, identification) and the capture
    /// time of their last fragment: `pool` holds the same ones, this counts what is given up.
    pending: HashMap<FragKey, i64>,
    ports: Option<Vec<u16>>,
    /// Byte offset of the next record.
    offset: u64,
    counts: PcapCounts,
    last_retain_ns: i64,
    failed: bool,
}

impl PcapUdp<std::io::BufReader<std::fs::File>> {
    /// Opens a pcap file.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        Self::new(std::io::BufReader::new(f), path)
    }
}

impl<R: Read> PcapUdp<R> {
    /// Reads a capture from `reader`; `path` names it in errors.
    pub fn new(reader: R, path: &Path) -> Result<Self, IoError> {
        let reader = PcapReader::new(reader).map_err(|e| IoError::Corrupt {
            file: path.to_path_buf(),
            what: "pcap header".into(),
            offset: 0,
            msg: e.to_string(),
        })?;
        let datalink = reader.header().datalink;
        match datalink {
            DataLink::ETHERNET | DataLink::RAW | DataLink::IPV4 | DataLink::LINUX_SLL => {}
            other => {
                return Err(IoError::Invalid {
                    path: path.to_path_buf(),
                    msg: format!("pcap link type {other:?} is not Ethernet, raw IP or Linux SLL"),
                })
            }
        }
        Ok(PcapUdp {
            reader,
            path: path.to_path_buf(),
            datalink,
            pool: IpDefragPool::new(),
            pending: HashMap::new(),
            ports: None,
            offset: 24,
            counts: PcapCounts::default(),
            last_retain_ns: i64::MIN,
            failed: false,
        })
    }

    /// Returns only the datagrams to these destination ports (the others are counted).
    pub fn ports(mut self, ports: &[u16]) -> Self {
        self.ports = Some(ports.to_vec());
        self
    }

    /// Counts so far.
    pub fn counts(&self) -> PcapCounts {
        self.counts
    }

    /// Parses one record's link layer and on; `None` when it yields no datagram.
    fn record(&mut self, data: &[u8], t_ns: i64) -> Option<UdpDatagram> {
        let sliced = match self.datalink {
            DataLink::ETHERNET => SlicedPacket::from_ethernet(data).ok(),
            DataLink::LINUX_SLL => SlicedPacket::from_linux_sll(data).ok(),
            _ => SlicedPacket::from_ip(data).ok(),
        };
        let Some(sliced) = sliced else {
            self.counts.malformed += 1;
            return None;
        };
        let fragmenting = match &sliced.net {
            Some(NetSlice::Ipv4(ip)) => ip.header().is_fragmenting_payload(),
            Some(NetSlice::Ipv6(ip)) => ip.is_payload_fragmented(),
            _ => false,
        };
        if !fragmenting {
            return match &sliced.transport {
                Some(TransportSlice::Udp(udp)) => self.accept(udp, t_ns),
                _ => {
                    self.counts.non_udp += 1;
                    None
                }
            };
        }
        self.counts.fragments += 1;
        self.expire(t_ns);
        let key = sliced.net.as_ref().and_then(frag_key);
        let result = self.pool.process_sliced_packet(&sliced, t_ns, ());
        if let Some(k) = key {
            match &result {
                Ok(None) => {
                    self.pending.insert(k, t_ns);
                }
                _ => {
                    self.pending.remove(&k);
                }
            }
        }
        match result {
            Ok(None) => None,
            Ok(Some(whole)) => {
                self.counts.reassembled += 1;
                let out = if whole.ip_number != etherparse::IpNumber::UDP {
                    self.counts.non_udp += 1;
                    None
                } else {
                    match UdpSlice::from_slice(&whole.payload) {
                        Ok(udp) => self.accept(&udp, t_ns),
                        Err(_) => {
                            self.counts.malformed += 1;
                            None
                        }
                    }
                };
                self.pool.return_buf(whole);
                out
            }
            Err(_) => {
                self.counts.incomplete += 1;
                None
            }
        }
    }

    /// Drops reassembly buffers older than [`FRAGMENT_TIMEOUT_NS`] (bounded memory).
    fn expire(&mut self, t_ns: i64) {
        if t_ns.saturating_sub(self.last_retain_ns) < FRAGMENT_TIMEOUT_NS / 10 {
            return;
        }
        self.last_retain_ns = t_ns;
        let cutoff = t_ns.saturating_sub(FRAGMENT_TIMEOUT_NS);
        let before = self.pending.len();
        self.pending.retain(|_, t| *t >= cutoff);
        self.counts.incomplete += (before - self.pending.len()) as u64;
        self.pool.retain(|t| *t >= cutoff);
    }

    fn accept(&mut self, udp: &UdpSlice, t_ns: i64) -> Option<UdpDatagram> {
        let dst_port = udp.destination_port();
        if let Some(ports) = &self.ports {
            if !ports.contains(&dst_port) {
                self.counts.other_ports += 1;
                return None;
            }
        }
        self.counts.datagrams += 1;
        Some(UdpDatagram {
            t_capture_ns: t_ns,
            src_port: udp.source_port(),
            dst_port,
            payload: udp.payload().to_vec(),
        })
    }
}

impl<R: Read> Iterator for PcapUdp<R> {
    type Item = Result<UdpDatagram, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        loop {
            let (data, t_ns) = match self.reader.next_packet()? {
                Ok(p) => (
                    p.data.into_owned(),
                    i64::try_from(p.timestamp.as_nanos()).unwrap_or(i64::MAX),
                ),
                Err(e) => {
                    self.failed = true;
                    return Some(Err(IoError::Corrupt {
                        file: self.path.clone(),
                        what: format!("pcap record {}", self.counts.records + 1),
                        offset: self.offset,
                        msg: e.to_string(),
                    }));
                }
            };
            self.counts.records += 1;
            self.offset += 16 + data.len() as u64;
            if let Some(d) = self.record(&data, t_ns) {
                return Some(Ok(d));
            }
        }
    }
}
