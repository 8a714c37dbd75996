//! Random damage to valid files, for the parser property tests: a few byte edits (replace,
//! delete, insert, truncate) of a valid input, or bytes that are random from the start.

use proptest::prelude::*;

/// One edit at a position given as a fraction of the input's length.
#[derive(Clone, Debug)]
pub enum Edit {
    Replace(f64, u8),
    Delete(f64),
    Insert(f64, u8),
    Truncate(f64),
}

/// Bytes that matter to the text formats (delimiters, signs, digits, quotes) or not at all.
fn byte() -> impl Strategy<Value = u8> {
    prop_oneof![
        prop::sample::select(b"()[]{}:,\"'.-+eE0123456789 \n\\/#nNaI".to_vec()),
        any::<u8>(),
    ]
}

fn edit() -> impl Strategy<Value = Edit> {
    let at = 0.0f64..1.0;
    prop_oneof![
        4 => (at.clone(), byte()).prop_map(|(p, b)| Edit::Replace(p, b)),
        2 => at.clone().prop_map(Edit::Delete),
        2 => (at.clone(), byte()).prop_map(|(p, b)| Edit::Insert(p, b)),
        1 => at.prop_map(Edit::Truncate),
    ]
}

/// `valid` damaged by one to eight edits, or (one case in five) random bytes.
pub fn damaged(valid: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        4 => prop::collection::vec(edit(), 1..8).prop_map(move |edits| apply(&valid, &edits)),
        1 => prop::collection::vec(any::<u8>(), 0..256),
    ]
}

fn apply(valid: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut bytes = valid.to_vec();
    for edit in edits {
        let at = |p: f64, len: usize| ((p * len as f64) as usize).min(len);
        match *edit {
            Edit::Replace(p, b) if !bytes.is_empty() => {
                let i = at(p, bytes.len() - 1);
                bytes[i] = b;
            }
            Edit::Delete(p) if !bytes.is_empty() => {
                bytes.remove(at(p, bytes.len() - 1));
            }
            Edit::Insert(p, b) => bytes.insert(at(p, bytes.len()), b),
            Edit::Truncate(p) => bytes.truncate(at(p, bytes.len())),
            _ => {}
        }
    }
    bytes
}
