//! Byte pacing of an emulated serial link (8N1: 10 bit times per byte).

use std::collections::VecDeque;

pub struct PacedLink {
    byte_time: f64,
    last: f64,
    queue: VecDeque<(f64, u8)>,
}

impl PacedLink {
    /// A baud rate of 0 is treated as 1 rather than dividing by zero.
    pub fn new(baud: u32) -> Self {
        PacedLink { byte_time: 10.0 / baud.max(1) as f64, last: f64::NEG_INFINITY, queue: VecDeque::new() }
    }

    /// Queues bytes sent at `now`; each one arrives one byte time after the
    /// previous one (or after `now`, if the line was idle).
    pub fn push(&mut self, now: f64, bytes: &[u8]) {
        for &b in bytes {
            let t = now.max(self.last) + self.byte_time;
            self.last = t;
            self.queue.push_back((t, b));
        }
    }

    /// Bytes whose arrival time is <= now, with their arrival times.
    pub fn pop_due(&mut self, now: f64) -> Vec<(f64, u8)> {
        let n = self.queue.iter().take_while(|(t, _)| *t <= now).count();
        self.queue.drain(..n).collect()
    }

    pub fn next_arrival(&self) -> Option<f64> {
        self.queue.front().map(|(t, _)| *t)
    }

    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pacing() {
        let mut l = PacedLink::new(115200);
        let bt = 10.0 / 115200.0;
        l.push(1.0, b"ab");
        l.push(1.0, b"c");
        assert_eq!(l.next_arrival(), Some(1.0 + bt));
        assert!(l.pop_due(1.0).is_empty());
        let due = l.pop_due(1.0 + 2.5 * bt);
        assert_eq!(due.len(), 2);
        assert_eq!(due[1], (1.0 + bt + bt, b'b'));
        assert_eq!(due[0].1, b'a');
        let rest = l.pop_due(10.0);
        assert_eq!(rest.len(), 1);
        assert!((rest[0].0 - (1.0 + 3.0 * bt)).abs() < 1e-12 && rest[0].1 == b'c');
        assert!(l.is_empty());
        l.push(20.0, b"d"); // idle line: starts from `now`
        assert_eq!(l.next_arrival(), Some(20.0 + bt));
    }
}
