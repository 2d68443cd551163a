//! One MCAP record from its opcode and body: [`parse_record`], the `mcap` crate's parser behind
//! a check of the one layout it does not bound (found by fuzzing the `mcap` target).

use mcap::records::{op, Record};
use mcap::McapError;

/// `mcap::parse_record`, except that an attachment record whose body is too short for its
/// header, data length and CRC is an [`McapError::UnexpectedEof`]: `mcap` 0.26 slices
/// `body[header_len..body.len() - 4]` before checking, which panics on such a body.
pub fn parse_record(opcode: u8, body: &[u8]) -> Result<Record<'_>, McapError> {
    if opcode == op::ATTACHMENT && !attachment_fits(body) {
        return Err(McapError::UnexpectedEof);
    }
    mcap::parse_record(opcode, body)
}

/// The attachment's header (log and create times, name, media type, data length) and CRC fit
/// in `body`: `8 + 8 + (4 + name) + (4 + media type) + 8 + 4 <= len`.
fn attachment_fits(body: &[u8]) -> bool {
    // The end of the length-prefixed string at `at`.
    let string_end = |at: usize| -> Option<usize> {
        let len = body.get(at..at.checked_add(4)?)?;
        let len = u32::from_le_bytes(len.try_into().ok()?);
        at.checked_add(4)?.checked_add(usize::try_from(len).ok()?)
    };
    let header_end = string_end(16)
        .and_then(string_end)
        .and_then(|at| at.checked_add(8));
    header_end
        .and_then(|at| at.checked_add(4))
        .is_some_and(|need| need <= body.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An attachment body: times, name, media type, data length, data, CRC (0: unchecked).
    fn attachment(name: &str, media: &str, data: &[u8]) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(&1u64.to_le_bytes());
        b.extend_from_slice(&2u64.to_le_bytes());
        for s in [name, media] {
            b.extend_from_slice(&(s.len() as u32).to_le_bytes());
            b.extend_from_slice(s.as_bytes());
        }
        b.extend_from_slice(&(data.len() as u64).to_le_bytes());
        b.extend_from_slice(data);
        b.extend_from_slice(&0u32.to_le_bytes());
        b
    }

    #[test]
    fn a_whole_attachment_parses_and_every_cut_of_it_is_an_error() {
        let body = attachment("truth.json", "application/json", b"{}");
        match parse_record(op::ATTACHMENT, &body) {
            Ok(Record::Attachment { header, data, .. }) => {
                assert_eq!(header.name, "truth.json");
                assert_eq!(&data[..], b"{}");
            }
            other => panic!("{other:?}"),
        }
        // Every shorter body (the crate panicked on those cut inside the CRC or data length).
        for n in 0..body.len() {
            assert!(
                parse_record(op::ATTACHMENT, &body[..n]).is_err(),
                "{n} bytes"
            );
        }
    }

    #[test]
    fn the_fuzzers_attachment_is_refused() {
        // The body of the record the `mcap` fuzz target found (crash-2d4648e3...): 33 bytes
        // whose strings are empty, so the header ends at 32 and the CRC would start past 29.
        let mut body = vec![0u8; 33];
        body[0..8].copy_from_slice(&1_000_000_000u64.to_le_bytes());
        assert!(!attachment_fits(&body));
        assert!(matches!(
            parse_record(op::ATTACHMENT, &body),
            Err(McapError::UnexpectedEof)
        ));
    }
}
