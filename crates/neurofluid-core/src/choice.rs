//! Choices an experiment names by a word (`matmul = "f16"`, `neighbour_search = "device"`) that
//! a process holds once the trainer has read the experiment: the names, their parsing with an
//! error that lists them, and the process's setting.

use std::sync::atomic::{AtomicU8, Ordering};

/// A choice among a fixed list of named values.
pub trait Choice: Copy + PartialEq + 'static {
    /// Every value; the first is the default.
    const ALL: &'static [Self];

    /// The name in files and on the command line.
    fn name(self) -> &'static str;

    /// The value named `s`, or an error that lists the names.
    fn parse(s: &str) -> Result<Self, String> {
        Self::ALL
            .iter()
            .copied()
            .find(|c| c.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|c| c.name()).collect();
                let (last, rest) = names.split_last().expect("a choice has values");
                let list = if rest.is_empty() {
                    (*last).to_string()
                } else {
                    format!("{} or {last}", rest.join(", "))
                };
                format!("expected {list}, got `{s}`")
            })
    }
}

/// A choice held by the process: the first value of [`Choice::ALL`] until set.
#[derive(Debug)]
pub struct ProcessChoice(AtomicU8);

impl ProcessChoice {
    /// The default value.
    pub const fn new() -> Self {
        Self(AtomicU8::new(0))
    }

    /// The value the process holds.
    pub fn get<C: Choice>(&self) -> C {
        C::ALL[usize::from(self.0.load(Ordering::Relaxed))]
    }

    /// Sets the value the process holds.
    pub fn set<C: Choice>(&self, value: C) {
        let i = C::ALL
            .iter()
            .position(|c| *c == value)
            .expect("a listed value");
        self.0.store(i as u8, Ordering::Relaxed);
    }
}

impl Default for ProcessChoice {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Three {
        A,
        B,
        C,
    }

    impl Choice for Three {
        const ALL: &'static [Self] = &[Three::A, Three::B, Three::C];
        fn name(self) -> &'static str {
            match self {
                Three::A => "a",
                Three::B => "b",
                Three::C => "c",
            }
        }
    }

    #[test]
    fn names_parse_and_the_process_holds_the_last_set() {
        for &t in Three::ALL {
            assert_eq!(Three::parse(t.name()), Ok(t));
        }
        assert_eq!(
            Three::parse("d").unwrap_err(),
            "expected a, b or c, got `d`"
        );
        let held = ProcessChoice::new();
        assert_eq!(held.get::<Three>(), Three::A);
        held.set(Three::C);
        assert_eq!(held.get::<Three>(), Three::C);
    }
}
