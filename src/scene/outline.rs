//! A tolerant structural scanner for RON (the "outline" of a document).
//!
//! It does not interpret values; it only finds the byte spans of values and the names and
//! positions of struct fields. That is enough to point a validation error at the line of
//! its field ([`locate_field`]) and for overrides to splice a replacement value into
//! serialised RON, without a second, position-keeping RON parser.

/// The 1-based line of a dotted field path (e.g. `model.tow.rho`, or with list indices
/// such as `data.objects[1].path[0].time`) in RON source text, or of its closest
/// enclosing field or element present in the text. `None` if nothing on the path appears
/// or the text cannot be scanned.
pub fn locate_field(text: &str, field: &str) -> Option<usize> {
    let root = parse_document(text)?;
    let mut node = &root;
    let mut found = None;
    'walk: for segment in field.split('.') {
        let mut parts = segment.split('[');
        let name = parts.next().unwrap_or(segment);
        match node.field(name) {
            Some(f) => {
                found = Some(f.name_start);
                node = &f.value;
            }
            None => break,
        }
        for index in parts {
            let Some(item) = index
                .trim_end_matches(']')
                .parse()
                .ok()
                .and_then(|i| node.item(i))
            else {
                break 'walk;
            };
            found = Some(item.start);
            node = item;
        }
    }
    found.map(|offset| line_col(text, offset).0)
}

/// A value and its byte span in the source.
pub(super) struct Node {
    pub start: usize,
    pub end: usize,
    pub kind: Kind,
}

/// The shape of a value.
pub(super) enum Kind {
    /// Number, string, char, bool, identifier (unit variant, `None`), ...
    Leaf,
    /// A struct-like body: `(a: 1, b: 2)` or `Name(a: 1)`.
    Fields(Vec<Field>),
    /// A tuple, list, newtype or map body: `(1, 2)`, `[1, 2]`, `Some(x)`, `{k: v}`.
    Items(Vec<Node>),
}

/// One `name: value` entry of a struct-like body.
pub(super) struct Field {
    pub name: String,
    pub name_start: usize,
    pub value: Node,
}

impl Node {
    /// The named field of this value, looking through newtype wrappers such as
    /// `Synthetic((...))` or `Some((...))`.
    pub fn field(&self, name: &str) -> Option<&Field> {
        match &self.unwrapped().kind {
            Kind::Fields(fields) => fields.iter().find(|f| f.name == name),
            _ => None,
        }
    }

    /// The `index`-th element of a tuple or list.
    pub fn item(&self, index: usize) -> Option<&Node> {
        match &self.kind {
            Kind::Items(items) => items.get(index),
            _ => None,
        }
    }

    /// Names of the fields reachable with [`Node::field`].
    pub fn field_names(&self) -> Vec<String> {
        match &self.unwrapped().kind {
            Kind::Fields(fields) => fields.iter().map(|f| f.name.clone()).collect(),
            _ => Vec::new(),
        }
    }

    /// Whether this node is a string literal in `src`.
    pub fn is_string(&self, src: &str) -> bool {
        let s = &src[self.start..self.end];
        s.starts_with('"') || s.starts_with("r\"") || s.starts_with("r#")
    }

    fn unwrapped(&self) -> &Node {
        let mut node = self;
        while let Kind::Items(items) = &node.kind {
            if items.len() != 1 {
                break;
            }
            node = &items[0];
        }
        node
    }
}

/// 1-based line and column (in characters) of a byte offset.
pub(super) fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let before = &src[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, before[line_start..].chars().count() + 1)
}

/// Scans a whole document: inner attributes (`#![enable(...)]`), one value, then
/// only whitespace and comments.
pub(super) fn parse_document(src: &str) -> Option<Node> {
    let mut p = Scanner {
        s: src.as_bytes(),
        i: 0,
    };
    loop {
        p.ws();
        if p.s[p.i..].starts_with(b"#![") {
            p.i += 2;
            p.skip_balanced()?;
        } else {
            break;
        }
    }
    let node = p.value(0)?;
    p.ws();
    (p.i == p.s.len()).then_some(node)
}

/// Scans text that must be exactly one value (surrounding whitespace allowed).
pub(super) fn parse_single(src: &str) -> Option<Node> {
    let mut p = Scanner {
        s: src.as_bytes(),
        i: 0,
    };
    let node = p.value(0)?;
    p.ws();
    (p.i == p.s.len()).then_some(node)
}

const MAX_DEPTH: usize = 128;

struct Scanner<'a> {
    s: &'a [u8],
    i: usize,
}

fn is_ident_start(b: u8) -> bool {
    b.is_ascii_alphabetic() || b == b'_' || b >= 0x80
}

fn is_ident_char(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b == b'_' || b >= 0x80
}

impl Scanner<'_> {
    fn peek(&self) -> Option<u8> {
        self.s.get(self.i).copied()
    }

    fn peek_at(&self, ahead: usize) -> Option<u8> {
        self.s.get(self.i + ahead).copied()
    }

    /// Skips whitespace, line comments and (nested) block comments.
    fn ws(&mut self) {
        loop {
            match (self.peek(), self.peek_at(1)) {
                (Some(b), _) if b.is_ascii_whitespace() => self.i += 1,
                (Some(b'/'), Some(b'/')) => {
                    while let Some(b) = self.peek() {
                        self.i += 1;
                        if b == b'\n' {
                            break;
                        }
                    }
                }
                (Some(b'/'), Some(b'*')) => {
                    self.i += 2;
                    let mut depth = 1;
                    while depth > 0 {
                        match (self.peek(), self.peek_at(1)) {
                            (None, _) => return,
                            (Some(b'/'), Some(b'*')) => {
                                depth += 1;
                                self.i += 2;
                            }
                            (Some(b'*'), Some(b'/')) => {
                                depth -= 1;
                                self.i += 2;
                            }
                            _ => self.i += 1,
                        }
                    }
                }
                _ => return,
            }
        }
    }

    /// Skips a bracketed group starting at `[`, `(` or `{`, honouring strings.
    fn skip_balanced(&mut self) -> Option<()> {
        let mut depth = 0usize;
        loop {
            self.ws();
            match self.peek()? {
                b'[' | b'(' | b'{' => {
                    depth += 1;
                    self.i += 1;
                }
                b']' | b')' | b'}' => {
                    depth = depth.checked_sub(1)?;
                    self.i += 1;
                    if depth == 0 {
                        return Some(());
                    }
                }
                b'"' => self.quoted()?,
                _ => self.i += 1,
            }
        }
    }

    fn value(&mut self, depth: usize) -> Option<Node> {
        if depth > MAX_DEPTH {
            return None;
        }
        self.ws();
        let start = self.i;
        let kind = match self.peek()? {
            b'(' => self.paren_body(depth)?,
            b'[' => {
                self.i += 1;
                Kind::Items(self.list(b']', depth)?)
            }
            b'{' => {
                self.i += 1;
                self.map(depth)?
            }
            b'"' | b'\'' => {
                self.quoted()?;
                Kind::Leaf
            }
            b'b' if matches!(self.peek_at(1), Some(b'"' | b'\'')) => {
                self.i += 1;
                self.quoted()?;
                Kind::Leaf
            }
            b'b' if self.peek_at(1) == Some(b'r') && self.raw_string_ahead(2) => {
                self.i += 1;
                self.raw_string()?;
                Kind::Leaf
            }
            b'r' if self.raw_string_ahead(1) => {
                self.raw_string()?;
                Kind::Leaf
            }
            b if is_ident_start(b) => {
                self.ident()?;
                let after = self.i;
                self.ws();
                if self.peek() == Some(b'(') {
                    self.paren_body(depth)?
                } else {
                    self.i = after;
                    Kind::Leaf
                }
            }
            b if b.is_ascii_digit() || matches!(b, b'+' | b'-' | b'.') => {
                self.i += 1;
                while self
                    .peek()
                    .is_some_and(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_'))
                    || (matches!(self.peek(), Some(b'+' | b'-'))
                        && matches!(self.s[self.i - 1], b'e' | b'E'))
                {
                    self.i += 1;
                }
                Kind::Leaf
            }
            _ => return None,
        };
        Some(Node {
            start,
            end: self.i,
            kind,
        })
    }

    /// Whether a raw string (`r"`, `r#"`, `r##"` ...) starts `ahead` bytes past a `r`
    /// at the cursor.
    fn raw_string_ahead(&self, ahead: usize) -> bool {
        let mut k = self.i + ahead;
        while self.s.get(k) == Some(&b'#') {
            k += 1;
        }
        self.s.get(k) == Some(&b'"')
    }

    /// Consumes `r#*"..."#*` with the cursor on the `r`.
    fn raw_string(&mut self) -> Option<()> {
        self.i += 1;
        let mut hashes = 0;
        while self.peek() == Some(b'#') {
            hashes += 1;
            self.i += 1;
        }
        self.i += 1; // opening quote
        loop {
            let b = self.peek()?;
            self.i += 1;
            if b == b'"' && (0..hashes).all(|k| self.peek_at(k) == Some(b'#')) {
                self.i += hashes;
                return Some(());
            }
        }
    }

    /// Consumes a string `"..."` or a char `'c'` (`'\n'`, `'\u{..}'`) with escapes, cursor on
    /// the opening quote; it ends at the same quote.
    fn quoted(&mut self) -> Option<()> {
        let quote = self.peek()?;
        self.i += 1;
        loop {
            match self.peek()? {
                b'\\' => self.i += 2,
                byte if byte == quote => {
                    self.i += 1;
                    return Some(());
                }
                _ => self.i += 1,
            }
        }
    }

    /// Consumes an identifier (optionally `r#`-prefixed) and returns its name.
    fn ident(&mut self) -> Option<String> {
        let raw = self.peek() == Some(b'r')
            && self.peek_at(1) == Some(b'#')
            && self.peek_at(2).is_some_and(is_ident_char);
        if raw {
            self.i += 2;
        }
        let start = self.i;
        if !self
            .peek()
            .is_some_and(if raw { is_ident_char } else { is_ident_start })
        {
            return None;
        }
        while self.peek().is_some_and(is_ident_char) {
            self.i += 1;
        }
        std::str::from_utf8(&self.s[start..self.i])
            .ok()
            .map(str::to_string)
    }

    /// A parenthesised body with the cursor on `(`: struct fields or tuple items.
    fn paren_body(&mut self, depth: usize) -> Option<Kind> {
        self.i += 1;
        let mut fields = Vec::new();
        let mut items = Vec::new();
        loop {
            self.ws();
            if self.peek()? == b')' {
                self.i += 1;
                break;
            }
            let save = self.i;
            let mut is_field = false;
            if self.peek().is_some_and(is_ident_start)
                && !self.raw_string_ahead(1)
                && let Some(name) = self.ident()
            {
                self.ws();
                if self.peek() == Some(b':') {
                    self.i += 1;
                    let value = self.value(depth + 1)?;
                    fields.push(Field {
                        name,
                        name_start: save,
                        value,
                    });
                    is_field = true;
                }
            }
            if !is_field {
                self.i = save;
                items.push(self.value(depth + 1)?);
            }
            self.ws();
            match self.peek()? {
                b',' => self.i += 1,
                b')' => {}
                _ => return None,
            }
        }
        Some(if fields.is_empty() {
            Kind::Items(items)
        } else {
            Kind::Fields(fields)
        })
    }

    /// Comma-separated values up to `close`, cursor just past the opener.
    fn list(&mut self, close: u8, depth: usize) -> Option<Vec<Node>> {
        let mut items = Vec::new();
        loop {
            self.ws();
            if self.peek()? == close {
                self.i += 1;
                return Some(items);
            }
            items.push(self.value(depth + 1)?);
            self.ws();
            match self.peek()? {
                b',' => self.i += 1,
                b if b == close => {}
                _ => return None,
            }
        }
    }

    /// A map body `{k: v, ...}`, cursor just past `{`; keeps the values.
    fn map(&mut self, depth: usize) -> Option<Kind> {
        let mut values = Vec::new();
        loop {
            self.ws();
            if self.peek()? == b'}' {
                self.i += 1;
                return Some(Kind::Items(values));
            }
            self.value(depth + 1)?;
            self.ws();
            if self.peek()? != b':' {
                return None;
            }
            self.i += 1;
            values.push(self.value(depth + 1)?);
            self.ws();
            match self.peek()? {
                b',' => self.i += 1,
                b'}' => {}
                _ => return None,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outline_finds_nested_fields_through_enums_and_newtypes() {
        let text = "#![enable(implicit_some)]\n// comment (with parens\n(\n  name: \"a) \\\"b\",\n  data: Synthetic((w: 3, s: r#\"x\"y\"#)),\n  densify: (\n    tat_form: Paper(beta: 1e-3, alpha: -2),\n  ),\n  /* block /* nested */ */ train: (background: [0, 0.5, 1]),\n)\n";
        assert_eq!(locate_field(text, "name"), Some(4));
        assert_eq!(locate_field(text, "data.w"), Some(5));
        assert_eq!(locate_field(text, "densify.tat_form.alpha"), Some(7));
        assert_eq!(locate_field(text, "densify.grad_threshold"), Some(6));
        assert_eq!(locate_field(text, "train.background[2]"), Some(9));
        assert_eq!(locate_field(text, "model.sh_degree"), None);
    }

    /// Char and byte literals end at their own quote, escapes included: brackets and the
    /// other kind of quote inside them do not open anything.
    #[test]
    fn outline_skips_char_and_byte_literals() {
        let text =
            "(\n  a: ')',\n  b: '\\'',\n  c: b\"(\\\"'\",\n  d: b'[',\n  q: '\"',\n  e: 2,\n)\n";
        assert_eq!(locate_field(text, "b"), Some(3));
        assert_eq!(locate_field(text, "q"), Some(6));
        assert_eq!(locate_field(text, "e"), Some(7));
        assert!(parse_single("'\"'").is_some());
        assert!(parse_single("\"'\"").is_some());
        assert!(parse_single("'a").is_none());
    }

    #[test]
    fn outline_rejects_trailing_garbage_and_unbalanced_values() {
        assert!(parse_single("(a: 1").is_none());
        assert!(parse_single("1 2").is_none());
        assert!(parse_single("Implementation(beta: 0.5, alpha: 2)").is_some());
        assert!(parse_single("-1.5e-3").is_some());
    }
}
