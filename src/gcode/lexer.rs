//! Lexing: one line of text → words, comments, checksum and delimiters set aside.

/// An error at a column of the current line.
#[derive(Debug)]
pub(super) struct Fault {
    pub(super) column: usize,
    pub(super) message: String,
}

impl Fault {
    pub(super) fn new(column: usize, message: impl Into<String>) -> Self {
        Fault { column, message: message.into() }
    }
}

/// A letter and its value.
#[derive(Clone, Copy, Debug)]
pub(super) struct Word {
    /// Upper-case ASCII letter.
    pub(super) letter: u8,
    /// The number, or None for a quoted string (`M862.3 P "MK3S"`).
    pub(super) value: Option<f64>,
    /// 1-based column of the letter.
    pub(super) column: usize,
}

#[derive(Clone, Debug)]
pub(super) enum LineKind {
    /// Words (possibly none).
    Words,
    /// A `%` program delimiter.
    Percent,
    /// A Klipper-style extended command (`EXCLUDE_OBJECT_START NAME=..`).
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
}

/// M-codes whose argument is free text up to the end of the line (Marlin).
pub(super) const TEXT_M_CODES: [u32; 7] = [230, 280, 320, 330, 1170, 1180, 9280];

#[derive(Default)]
pub(super) struct Lexer {
    pub(super) chars: Vec<char>,
    pub(super) words: Vec<Word>,
    pub(super) number: String,
}

impl Lexer {
    /// Splits one line (without its line end) into words; comments, checksum and delimiters aside.
    pub(super) fn lex(&mut self, bytes: &[u8]) -> Result<Lexed, Fault> {
        self.chars.clear();
        self.words.clear();
        self.chars.extend(String::from_utf8_lossy(bytes).chars());
        let mut lexed = Lexed { kind: LineKind::Words, comment: None, message_comment: None, block_delete: false, first_column: 1 };
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
        if let Some(name) = self.extended_command(i) {
            lexed.kind = LineKind::Extended(name);
            return Ok(lexed);
        }
        self.words_from(i, bytes, &mut lexed)?;
        Ok(lexed)
    }

    pub(super) fn skip_blank(&self, mut i: usize) -> usize {
        while i < self.chars.len() && is_blank(self.chars[i]) {
            i += 1;
        }
        i
    }

    /// A first token like `SET_PRESSURE_ADVANCE`: a letter, then letters, digits and at least one
    /// underscore, then a blank, a `;` or the end of the line.
    pub(super) fn extended_command(&self, i: usize) -> Option<String> {
        let token = &self.chars[i.min(self.chars.len())..];
        let length = token.iter().take_while(|c| c.is_ascii_alphanumeric() || **c == '_').count();
        let token = &token[..length];
        let starts_with_letter = token.first().is_some_and(|c| c.is_ascii_alphabetic());
        let ends_token = self.chars.get(i + length).is_none_or(|c| is_blank(*c) || *c == ';');
        (starts_with_letter && token.contains(&'_') && ends_token).then(|| token.iter().collect::<String>().to_ascii_uppercase())
    }

    pub(super) fn words_from(&mut self, mut i: usize, bytes: &[u8], lexed: &mut Lexed) -> Result<(), Fault> {
        loop {
            i = self.skip_blank(i);
            let Some(&c) = self.chars.get(i) else { return Ok(()) };
            match c {
                ';' => {
                    lexed.comment = Some(i + 1..self.chars.len());
                    return Ok(());
                }
                '(' => i = self.paren_comment(i, lexed)?,
                '*' => return self.checksum(i, bytes),
                'O' | 'o' => return Err(Fault::new(i + 1, "O words (subroutines, loops) are not supported")),
                'A'..='Z' | 'a'..='z' => {
                    i = self.word(i)?;
                    if self.starts_text_argument() {
                        return Ok(());
                    }
                }
                '#' => return Err(Fault::new(i + 1, "parameters (#) are not supported")),
                '[' => return Err(Fault::new(i + 1, "expressions ([...]) are not supported")),
                _ => return Err(Fault::new(i + 1, format!("unexpected character {c:?} where a word letter should be"))),
            }
        }
    }

    /// Skips a `( ... )` comment starting at `i`; returns the index after it.
    pub(super) fn paren_comment(&self, i: usize, lexed: &mut Lexed) -> Result<usize, Fault> {
        let close = self.chars[i + 1..].iter().position(|c| *c == ')').map(|p| i + 1 + p);
        let close = close.ok_or_else(|| Fault::new(i + 1, "unclosed '(' comment"))?;
        let body = &self.chars[self.skip_blank(i + 1).min(close)..close];
        if body.len() >= 4 && body[..4].iter().zip("msg,".chars()).all(|(c, m)| c.to_ascii_lowercase() == m) {
            lexed.message_comment = Some(i + 1);
        }
        Ok(close + 1)
    }

    /// Checks a `*NN` checksum at `i`: the XOR of the line's bytes before the `*` (Marlin/RepRap).
    pub(super) fn checksum(&self, i: usize, bytes: &[u8]) -> Result<(), Fault> {
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
    pub(super) fn word(&mut self, i: usize) -> Result<usize, Fault> {
        let letter = self.chars[i].to_ascii_uppercase() as u8;
        let column = i + 1;
        let j = self.skip_blank(i + 1);
        match self.chars.get(j) {
            Some('[') => return Err(Fault::new(column, "expressions ([...]) are not supported")),
            Some('#') => return Err(Fault::new(column, "parameters (#) are not supported")),
            _ => {}
        }
        if self.chars.get(j) == Some(&'"') {
            let end = self.quoted_string(j, column)?;
            self.words.push(Word { letter, value: None, column });
            return Ok(end);
        }
        let (value, end) = self.number(j, letter as char, column)?;
        self.words.push(Word { letter, value: Some(value), column });
        Ok(end)
    }

    /// Skips a `"..."` string (`""` is a quote inside it); returns the index after it.
    pub(super) fn quoted_string(&self, mut j: usize, column: usize) -> Result<usize, Fault> {
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
    pub(super) fn number(&mut self, mut j: usize, letter: char, column: usize) -> Result<(f64, usize), Fault> {
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
        if let Some(e @ ('e' | 'E')) = self.chars.get(j) {
            let token = self.rest_of_token(column);
            let message =
                format!("{letter}{token}: '{e}' right after a number: exponents are not G-code, and an E word needs a space before it");
            return Err(Fault::new(column, message));
        }
        let value: f64 = self.number.parse().map_err(|_| self.malformed(letter, column))?;
        if !value.is_finite() {
            return Err(Fault::new(column, format!("number out of range after {letter}")));
        }
        Ok((value, j))
    }

    pub(super) fn malformed(&self, letter: char, column: usize) -> Fault {
        match self.rest_of_token(column) {
            token if token.is_empty() => Fault::new(column, format!("{letter} without a number")),
            token => Fault::new(column, format!("malformed number after {letter}: {token:?}")),
        }
    }

    /// The characters after a word letter up to the next blank or comment, for messages.
    pub(super) fn rest_of_token(&self, column: usize) -> String {
        self.chars[column.min(self.chars.len())..].iter().take_while(|c| !is_blank(**c) && !matches!(c, ';' | '(')).take(20).collect()
    }

    /// True if the last word is an M-code whose argument is free text (`M117 Printing...`).
    pub(super) fn starts_text_argument(&self) -> bool {
        let only_codes = self.words.iter().all(|w| matches!(w.letter, b'M' | b'N'));
        match self.words.last() {
            Some(Word { letter: b'M', value: Some(v), .. }) => only_codes && code_tenths(*v).is_some_and(|c| TEXT_M_CODES.contains(&c)),
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
