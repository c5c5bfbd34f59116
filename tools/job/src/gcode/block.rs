//! Blocks: the words of one line, grouped into codes and at most one parameter per letter.

use super::lexer::{Fault, Value, Word, code_tenths};

/// A G- or M-code on a line.
#[derive(Clone, Copy, Debug)]
pub(super) struct Code {
    pub(super) tenths: u32,
    pub(super) column: usize,
}

/// A parameter word (any letter but G, M, N).
#[derive(Clone, Copy, Debug)]
pub(super) struct Param {
    pub(super) value: Value,
    pub(super) column: usize,
}

impl Param {
    /// The number; an error naming the column for a string or a bare letter.
    pub(super) fn number(&self, letter: u8) -> Result<f64, Fault> {
        let letter = letter as char;
        match self.value {
            Value::Number(v) => Ok(v),
            Value::Text => Err(Fault::new(self.column, format!("{letter} needs a number, not a string"))),
            Value::Bare => Err(Fault::new(self.column, format!("{letter} without a number"))),
        }
    }
}

/// The words of one line: its codes, and at most one parameter per letter.
#[derive(Default)]
pub(super) struct Block {
    pub(super) g: Vec<Code>,
    pub(super) m: Vec<Code>,
    pub(super) params: [Option<Param>; 26],
    /// Letters consumed by what the line does (bit i = letter 'A' + i).
    pub(super) used: u32,
}

pub(super) fn letter_index(letter: u8) -> usize {
    usize::from(letter.wrapping_sub(b'A')).min(25)
}

impl Block {
    pub(super) fn fill(&mut self, words: &[Word]) -> Result<(), Fault> {
        self.g.clear();
        self.m.clear();
        self.params = [None; 26];
        self.used = 0;
        for word in words {
            self.add(word)?;
        }
        Ok(())
    }

    pub(super) fn add(&mut self, word: &Word) -> Result<(), Fault> {
        let letter = word.letter as char;
        let number = |w: &Word| Param { value: w.value, column: w.column }.number(w.letter);
        match word.letter {
            b'G' | b'M' => {
                let value = number(word)?;
                let tenths = code_tenths(value).ok_or_else(|| Fault::new(word.column, format!("invalid code number {letter}{value}")))?;
                let code = Code { tenths, column: word.column };
                if word.letter == b'G' { self.g.push(code) } else { self.m.push(code) }
            }
            b'N' => {
                number(word)?;
            }
            _ => {
                let slot = &mut self.params[letter_index(word.letter)];
                if let Some(first) = slot {
                    // Text glued to a letter (`M220 Sfast`) reads as more words, a letter always
                    // starting one as in every firmware: say so when a bare letter is involved.
                    let hint = if matches!(first.value, Value::Bare) || matches!(word.value, Value::Bare) {
                        " (a letter always starts a word, so text after a letter reads as more words: was a number meant?)"
                    } else {
                        ""
                    };
                    return Err(Fault::new(word.column, format!("word {letter} given twice on one line{hint}")));
                }
                *slot = Some(Param { value: word.value, column: word.column });
            }
        }
        Ok(())
    }

    pub(super) fn has(&self, letter: u8) -> bool {
        self.params[letter_index(letter)].is_some()
    }

    pub(super) fn has_any(&self, letters: &[u8]) -> bool {
        letters.iter().any(|l| self.has(*l))
    }

    /// Column of `letter`'s word (0 if absent).
    pub(super) fn column(&self, letter: u8) -> usize {
        self.params[letter_index(letter)].map_or(0, |p| p.column)
    }

    /// The number of `letter`'s word, marking it used; an error if it is a string or bare.
    pub(super) fn take(&mut self, letter: u8) -> Result<Option<f64>, Fault> {
        self.take_param(letter).map(|p| p.number(letter)).transpose()
    }

    /// `letter`'s word as written, marking it used.
    pub(super) fn take_param(&mut self, letter: u8) -> Option<Param> {
        let param = self.params[letter_index(letter)]?;
        self.used |= 1 << letter_index(letter);
        Some(param)
    }

    /// True if the line has any G- or M-code besides the one at `column`.
    pub(super) fn has_other_code(&self, column: usize) -> bool {
        self.g.iter().chain(&self.m).any(|c| c.column != column)
    }

    /// Parameters present but not consumed, in letter order.
    pub(super) fn unused(&self) -> impl Iterator<Item = (u8, Param)> + '_ {
        (0..26u8).filter(|i| self.used & (1 << i) == 0).filter_map(|i| self.params[usize::from(i)].map(|p| (b'A' + i, p)))
    }

    pub(super) fn mark_all_used(&mut self) {
        self.used = u32::MAX;
    }
}
