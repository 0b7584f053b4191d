//! The host's end of the command port: bytes queued at chosen virtual instants, and every byte the
//! firmware sent, with the instant its stop bit ended.

use std::collections::VecDeque;

use rigless::chip::uart::Peer;
use rigless::chip::Timeline;
use rigless::snapshot::Store;
use rigless::time::VirtualNanos;

/// The host on USART2 (rigless's `uart::Peer`).
#[derive(Debug, Default)]
pub struct HostPort {
    /// Bytes to put on the line, each no earlier than its instant, oldest first.
    outgoing: VecDeque<(VirtualNanos, u16)>,
    /// Every byte the firmware sent, with the instant it arrived.
    received: Vec<(VirtualNanos, u8)>,
}

impl HostPort {
    /// Queue `bytes` to be put on the line from `at` on, one after the other at the port's baud.
    pub fn send_at(&mut self, at: VirtualNanos, bytes: &[u8]) {
        self.outgoing
            .extend(bytes.iter().map(|&b| (at, u16::from(b))));
    }

    /// Every byte received so far, with its arrival instant.
    pub fn received_bytes(&self) -> &[(VirtualNanos, u8)] {
        &self.received
    }
}

impl Store for HostPort {}

impl Peer for HostPort {
    fn receive(&mut self, word: u16, context: &mut Timeline<'_, '_>) {
        self.received.push((context.now(), word as u8));
    }

    fn transmit(&mut self, now: VirtualNanos) -> Option<u16> {
        let (at, _) = self.outgoing.front()?;
        if *at <= now {
            self.outgoing.pop_front().map(|(_, w)| w)
        } else {
            None
        }
    }
}
