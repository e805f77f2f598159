//! The software transmit queue in front of bxCAN's three mailboxes.
//!
//! First in, first out, which keeps every stream of one COB-ID in order (SDO segments, EMCY
//! raise then clear). The mailboxes then sort what they hold by CAN priority. bxCAN accepts a
//! frame only when it outranks every pending one; when all three mailboxes are full it
//! aborts the lowest-priority pending frame and hands it back. That frame was queued before
//! anything still waiting here, so [`TxQueue::requeue`] puts it back at the head.

use super::Frame;

/// A bounded frame queue, `N` frames at most.
pub struct TxQueue<const N: usize> {
    frames: heapless::Deque<Frame, N>,
}

impl<const N: usize> TxQueue<N> {
    /// An empty queue.
    pub const fn new() -> Self {
        Self {
            frames: heapless::Deque::new(),
        }
    }

    /// Queues a frame at the tail. Gives it back when the queue is full.
    pub fn push(&mut self, frame: Frame) -> Result<(), Frame> {
        self.frames.push_back(frame)
    }

    /// Puts a frame that left the queue earlier (displaced from a mailbox) back at the head.
    pub fn requeue(&mut self, frame: Frame) -> Result<(), Frame> {
        self.frames.push_front(frame)
    }

    /// The frame that goes next.
    pub fn front(&self) -> Option<&Frame> {
        self.frames.front()
    }

    /// Removes the frame that goes next.
    pub fn pop_front(&mut self) -> Option<Frame> {
        self.frames.pop_front()
    }

    /// Discards every frame waiting.
    pub fn clear(&mut self) {
        self.frames.clear();
    }

    /// Frames waiting.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// No frame waiting.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

impl<const N: usize> Default for TxQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}
