//! Lexing: one line of text → words (or an extended command and its `KEY=VALUE` parameters), with
//! comments, checksum, delimiters and free-text arguments set aside. The lexer knows the shape of a
//! line, not what any code means; the one exception is the short list of M-codes whose argument is
//! free text ([`TEXT_M_CODES`]), because their text must not be read as words.

/// An error at a column of the current line.
#[derive(Clone, Debug)]
pub(super) struct Fault {
    pub(super) column: usize,
    pub(super) message: String,
}

impl Fault {
    pub(super) fn new(column: usize, message: impl Into<String>) -> Self {
        Fault { column, message: message.into() }
    }
}

/// What follows a word's letter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Value {
    /// A number.
    Number(f64),
    /// A quoted string (`M862.3 P "MK3S"`).
    Text,
    /// Nothing: a flag (`M84 X Y E`, `G28 X`). Whether a flag is allowed is up to the code that
    /// reads it: homing and motors-off take them; a motion's axis word without a number is an error.
    Bare,
}

/// A letter and its value.
#[derive(Clone, Copy, Debug)]
pub(super) struct Word {
    /// Upper-case ASCII letter.
    pub(super) letter: u8,
    pub(super) value: Value,
    /// 1-based column of the letter.
    pub(super) column: usize,
}

/// A `KEY=VALUE` parameter of an extended command (key upper-cased, value as written, quotes removed).
#[derive(Clone, Debug)]
pub(super) struct ExtendedParam {
    pub(super) key: String,
    pub(super) value: String,
    /// 1-based column of the value's first character.
    pub(super) column: usize,
}

#[derive(Clone, Debug)]
pub(super) enum LineKind {
    /// Words (possibly none).
    Words,
    /// A `%` program delimiter.
    Percent,
    /// A Klipper-style extended command (`EXCLUDE_OBJECT_START NAME=..`), upper-cased; its
    /// parameters are in [`Lexer::params`].
    Extended(String),
}

/// What a line holds besides its words.
#[derive(Clone, Debug)]
pub(super) struct Lexed {
    pub(super) kind: LineKind,
    /// Character range of the `;` comment's text (after the `;`).
    pub(super) comment: Option<std::ops::Range<usize>>,
    /// Column of a `(msg, ...)` comment.
    pub(super) message_comment: Option<usize>,
    /// The line starts with `/` (block delete).
    pub(super) block_delete: bool,
    /// Column of the first non-blank character.
    pub(super) first_column: usize,
    /// On a line that starts with an M-code (lenient lexing only): the first word that could not be
    /// read; the rest of the line was set aside. The interpreter decides whether that matters: not
    /// for an M-code it does not act on (its parameters are not read), an error otherwise.
    pub(super) unread: Option<Fault>,
    /// An extended command's parameter that is not `KEY=VALUE` (its column and text).
    pub(super) malformed_param: Option<Fault>,
}

/// M-codes whose argument is free text up to the end of the line, in tenths: Marlin's file and
/// message codes (`M23 name`, `M28`, `M30 name` is not here: it ends RS274 programs, `M32`, `M33`,
/// `M117 text`, `M118 text`, `M928 name`), Marlin's `M16 printer` and Bambu's `M1002 action : 2`.
pub(super) const TEXT_M_CODES: [u32; 9] = [160, 230, 280, 320, 330, 1170, 1180, 9280, 10020];

#[derive(Default)]
pub(super) struct Lexer {
    pub(super) chars: Vec<char>,
    pub(super) words: Vec<Word>,
    /// Parameters of the last extended command.
    pub(super) params: Vec<ExtendedParam>,
    number: String,
    /// Set the rest of an M-code line aside at its first unreadable word instead of failing
    /// (firmware dialect: firmwares ignore what they do not understand in parameters).
    pub(super) lenient: bool,
}

impl Lexer {
    pub(super) fn new(lenient: bool) -> Self {
        Lexer { lenient, ..Lexer::default() }
    }

    /// Splits one line (without its line end) into words; comments, checksum and delimiters aside.
    pub(super) fn lex(&mut self, bytes: &[u8]) -> Result<Lexed, Fault> {
        self.chars.clear();
        self.words.clear();
        self.params.clear();
        self.chars.extend(String::from_utf8_lossy(bytes).chars());
        let mut lexed = Lexed {
            kind: LineKind::Words,
            comment: None,
            message_comment: None,
            block_delete: false,
            first_column: 1,
            unread: None,
            malformed_param: None,
        };
        let mut i = self.skip_blank(0);
        lexed.first_column = i + 1;
        if self.chars.get(i) == Some(&'/') {
            lexed.block_delete = true;
            i = self.skip_blank(i + 1);
        }
        if self.chars.get(i) == Some(&'%') {
            lexed.kind = LineKind::Percent;
            return Ok(lexed);
        }
        if let Some((name, end)) = self.extended_command(i) {
            lexed.kind = LineKind::Extended(name);
            self.extended_params(end, &mut lexed);
            return Ok(lexed);
        }
        self.words_from(i, bytes, &mut lexed)?;
        Ok(lexed)
    }

    fn skip_blank(&self, mut i: usize) -> usize {
        while i < self.chars.len() && is_blank(self.chars[i]) {
            i += 1;
        }
        i
    }

    /// A first token like `SET_PRESSURE_ADVANCE` or `PAUSE`: letters, digits and underscores that
    /// start with two letters or contain an underscore, ending at a blank, a `;` or the line's end.
    /// A G-code word is one letter and a number (`G1`, `M84`), so the two cannot be confused; this is
    /// Klipper's own rule (a command whose second character is not a digit is extended).
    fn extended_command(&self, i: usize) -> Option<(String, usize)> {
        let token = &self.chars[i.min(self.chars.len())..];
        let length = token.iter().take_while(|c| c.is_ascii_alphanumeric() || **c == '_').count();
        let token = &token[..length];
        let starts_with_letter = token.first().is_some_and(|c| c.is_ascii_alphabetic());
        let two_letters = token.len() >= 2 && token[1].is_ascii_alphabetic();
        let ends_token = self.chars.get(i + length).is_none_or(|c| is_blank(*c) || *c == ';');
        let extended = starts_with_letter && (two_letters || token.contains(&'_')) && ends_token;
        extended.then(|| (token.iter().collect::<String>().to_ascii_uppercase(), i + length))
    }

    /// Reads `KEY=VALUE` parameters from `i` to the end of the line or a `;` comment (Klipper's
    /// syntax: a value runs to the next blank unless it is in double quotes).
    fn extended_params(&mut self, mut i: usize, lexed: &mut Lexed) {
        loop {
            i = self.skip_blank(i);
            let Some(&c) = self.chars.get(i) else { return };
            if c == ';' {
                lexed.comment = Some(i + 1..self.chars.len());
                return;
            }
            let key_length = self.chars[i..].iter().take_while(|c| c.is_ascii_alphanumeric() || **c == '_').count();
            if key_length == 0 || self.chars.get(i + key_length) != Some(&'=') {
                let token: String = self.chars[i..].iter().take_while(|c| !is_blank(**c) && **c != ';').take(20).collect();
                if lexed.malformed_param.is_none() {
                    lexed.malformed_param = Some(Fault::new(i + 1, format!("parameter {token:?} is not KEY=VALUE")));
                }
                i += self.chars[i..].iter().take_while(|c| !is_blank(**c) && **c != ';').count();
                continue;
            }
            let key: String = self.chars[i..i + key_length].iter().collect::<String>().to_ascii_uppercase();
            let start = i + key_length + 1;
            let (value, end) = if self.chars.get(start) == Some(&'"') {
                let close = self.chars[start + 1..].iter().position(|c| *c == '"').map_or(self.chars.len(), |p| start + 1 + p);
                (self.chars[start + 1..close].iter().collect(), (close + 1).min(self.chars.len()))
            } else {
                let length = self.chars[start..].iter().take_while(|c| !is_blank(**c) && **c != ';').count();
                (self.chars[start..start + length].iter().collect(), start + length)
            };
            self.params.push(ExtendedParam { key, value, column: start + 1 });
            i = end;
        }
    }

    fn words_from(&mut self, mut i: usize, bytes: &[u8], lexed: &mut Lexed) -> Result<(), Fault> {
        loop {
            i = self.skip_blank(i);
            let Some(&c) = self.chars.get(i) else { return Ok(()) };
            let step = match c {
                ';' => {
                    lexed.comment = Some(i + 1..self.chars.len());
                    return Ok(());
                }
                '(' => self.paren_comment(i, lexed),
                '*' => return self.checksum(i, bytes),
                'O' | 'o' => Err(Fault::new(i + 1, "O words (subroutines, loops) are not supported")),
                'A'..='Z' | 'a'..='z' => self.word(i),
                '#' => Err(Fault::new(i + 1, "parameters (#) are not supported")),
                '[' => Err(Fault::new(i + 1, "expressions ([...]) are not supported")),
                _ => Err(Fault::new(i + 1, format!("unexpected character {c:?} where a word letter should be"))),
            };
            match step {
                Ok(next) => i = next,
                Err(fault) if self.lenient && self.starts_with_m_code() => {
                    lexed.unread = Some(fault);
                    return Ok(());
                }
                Err(fault) => return Err(fault),
            }
            if self.starts_text_argument() {
                return Ok(());
            }
        }
    }

    /// True if the first code word read so far is an M-code (`N10 M486 AShape-Box`).
    pub(super) fn starts_with_m_code(&self) -> bool {
        self.words.iter().find(|w| w.letter != b'N').is_some_and(|w| w.letter == b'M')
    }

    /// Skips a `( ... )` comment starting at `i`; returns the index after it.
    fn paren_comment(&self, i: usize, lexed: &mut Lexed) -> Result<usize, Fault> {
        let close = self.chars[i + 1..].iter().position(|c| *c == ')').map(|p| i + 1 + p);
        let close = close.ok_or_else(|| Fault::new(i + 1, "unclosed '(' comment"))?;
        let body = &self.chars[self.skip_blank(i + 1).min(close)..close];
        if body.len() >= 4 && body[..4].iter().zip("msg,".chars()).all(|(c, m)| c.to_ascii_lowercase() == m) {
            lexed.message_comment = Some(i + 1);
        }
        Ok(close + 1)
    }

    /// Checks a `*NN` checksum at `i`: the XOR of the line's bytes before the `*` (Marlin/RepRap).
    fn checksum(&self, i: usize, bytes: &[u8]) -> Result<(), Fault> {
        let digits: String = self.chars[i + 1..].iter().take_while(|c| c.is_ascii_digit()).collect();
        let rest = self.skip_blank(i + 1 + digits.len());
        if digits.is_empty() || (rest < self.chars.len() && self.chars[rest] != ';') {
            return Err(Fault::new(i + 1, "malformed checksum: '*' must be followed by digits at the end of the line"));
        }
        let prefix_bytes: usize = self.chars[..i].iter().map(|c| c.len_utf8()).sum();
        let expected = bytes.get(..prefix_bytes).unwrap_or(bytes).iter().fold(0u8, |x, b| x ^ b);
        match digits.parse::<u32>() {
            Ok(given) if given == u32::from(expected) => Ok(()),
            _ => Err(Fault::new(i + 1, format!("checksum mismatch: line says *{digits}, its bytes give *{expected}"))),
        }
    }

    /// Reads the word whose letter is at `i`; returns the index after it.
    fn word(&mut self, i: usize) -> Result<usize, Fault> {
        let letter = self.chars[i].to_ascii_uppercase() as u8;
        let column = i + 1;
        let j = self.skip_blank(i + 1);
        match self.chars.get(j) {
            Some('[') => return Err(Fault::new(column, "expressions ([...]) are not supported")),
            Some('#') => return Err(Fault::new(column, "parameters (#) are not supported")),
            _ => {}
        }
        if self.chars.get(j) == Some(&'"') {
            if matches!(letter, b'G' | b'M' | b'N') {
                return Err(Fault::new(column, format!("{} needs a number, not a string", letter as char)));
            }
            let end = self.quoted_string(j, column)?;
            self.words.push(Word { letter, value: Value::Text, column });
            return Ok(end);
        }
        if self.is_bare(j) {
            if matches!(letter, b'G' | b'M' | b'N') {
                return Err(Fault::new(column, format!("{} without a number", letter as char)));
            }
            self.words.push(Word { letter, value: Value::Bare, column });
            return Ok(j);
        }
        let (value, end) = self.number(j, letter as char, column)?;
        self.words.push(Word { letter, value: Value::Number(value), column });
        Ok(end)
    }

    /// True if a word's letter followed by `next` has no value: the line or a comment follows, or
    /// another word's letter, with or without a blank before it (`X Y`, packed `XY`: a letter
    /// always starts a word). `X-` and `X.` are malformed numbers instead.
    fn is_bare(&self, next: usize) -> bool {
        match self.chars.get(next) {
            None | Some(';' | '(' | '*') => true,
            Some(c) => c.is_ascii_alphabetic(),
        }
    }

    /// Skips a `"..."` string (`""` is a quote inside it); returns the index after it.
    fn quoted_string(&self, mut j: usize, column: usize) -> Result<usize, Fault> {
        j += 1;
        loop {
            match self.chars.get(j) {
                None => return Err(Fault::new(column, "unclosed quoted string")),
                Some('"') if self.chars.get(j + 1) == Some(&'"') => j += 2,
                Some('"') => return Ok(j + 1),
                Some(_) => j += 1,
            }
        }
    }

    /// Reads `[+-]digits[.digits]` at `j` for the word `letter` at `column`.
    fn number(&mut self, mut j: usize, letter: char, column: usize) -> Result<(f64, usize), Fault> {
        self.number.clear();
        if let Some(&sign @ ('+' | '-')) = self.chars.get(j) {
            self.number.push(sign);
            j += 1;
        }
        let mut digits = 0;
        let mut seen_point = false;
        while let Some(&c) = self.chars.get(j) {
            if c.is_ascii_digit() {
                digits += 1;
            } else if c == '.' && !seen_point {
                seen_point = true;
            } else {
                break;
            }
            self.number.push(c);
            j += 1;
        }
        if digits == 0 || self.chars.get(j) == Some(&'.') {
            return Err(self.malformed(letter, column));
        }
        // A letter right after the number starts the next word (`X120.5E22.97`: X, then E), as
        // every firmware reads a packed line: G-code has no exponents.
        let value: f64 = self.number.parse().map_err(|_| self.malformed(letter, column))?;
        if !value.is_finite() {
            return Err(Fault::new(column, format!("number out of range after {letter}")));
        }
        Ok((value, j))
    }

    fn malformed(&self, letter: char, column: usize) -> Fault {
        match self.rest_of_token(column) {
            token if token.is_empty() => Fault::new(column, format!("{letter} without a number")),
            token => Fault::new(column, format!("malformed number after {letter}: {token:?}")),
        }
    }

    /// The characters after a word letter up to the next blank or comment, for messages.
    fn rest_of_token(&self, column: usize) -> String {
        self.chars[column.min(self.chars.len())..].iter().take_while(|c| !is_blank(**c) && !matches!(c, ';' | '(')).take(20).collect()
    }

    /// True if the last word is an M-code whose argument is free text (`M117 Printing...`).
    fn starts_text_argument(&self) -> bool {
        let only_codes = self.words.iter().all(|w| matches!(w.letter, b'M' | b'N'));
        match self.words.last() {
            Some(Word { letter: b'M', value: Value::Number(v), .. }) => {
                only_codes && code_tenths(*v).is_some_and(|c| TEXT_M_CODES.contains(&c))
            }
            _ => false,
        }
    }
}

pub(super) fn is_blank(c: char) -> bool {
    matches!(c, ' ' | '\t' | '\r' | '\x0b' | '\x0c')
}

/// A code number in tenths (`G92.1` → 921), if it is a non-negative number with at most one decimal.
pub(super) fn code_tenths(value: f64) -> Option<u32> {
    let tenths = value * 10.0;
    let rounded = tenths.round();
    ((tenths - rounded).abs() < 1e-6 && (0.0..=1e7).contains(&rounded)).then_some(rounded as u32)
}

/// `G92.1`, `M104`.
pub(super) fn code_name(letter: char, tenths: u32) -> String {
    if tenths.is_multiple_of(10) { format!("{letter}{}", tenths / 10) } else { format!("{letter}{}.{}", tenths / 10, tenths % 10) }
}

/// A number that is finite, else a fault at its column.
pub(super) fn finite(value: f64, column: usize) -> Result<f64, Fault> {
    if value.is_finite() { Ok(value) } else { Err(Fault::new(column, "value out of range (not finite)")) }
}

/// A length (m): finite and within ±[`MAX_COORDINATE`](super::MAX_COORDINATE), so later arithmetic cannot overflow.
pub(super) fn bounded(value: f64, column: usize) -> Result<f64, Fault> {
    match finite(value, column)? {
        v if v.abs() <= super::MAX_COORDINATE => Ok(v),
        v => Err(Fault::new(column, format!("value out of range: {v:e} m is beyond ±{:e} m", super::MAX_COORDINATE))),
    }
}
