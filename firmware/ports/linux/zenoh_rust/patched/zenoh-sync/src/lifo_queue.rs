//
// Copyright (c) 2023 ZettaScale Technology
//
// This program and the accompanying materials are made available under the
// terms of the Eclipse Public License 2.0 which is available at
// http://www.eclipse.org/legal/epl-2.0, or the Apache License, Version 2.0
// which is available at https://www.apache.org/licenses/LICENSE-2.0.
//
// SPDX-License-Identifier: EPL-2.0 OR Apache-2.0
//
// Contributors:
//   ZettaScale Zenoh Team, <zenoh@zettascale.tech>
//
use std::sync::{Condvar, Mutex};

use zenoh_collections::StackBuffer;
use zenoh_core::zlock;

// Condvar::notify_one makes a futex syscall whether or not a thread waits; the receive path
// pulls and returns one buffer per message, so every message paid two wakes of nobody. The
// waiters are counted under the buffer's lock, and a notify is made only when one waits.
#[derive(Debug)]
struct Stack<T> {
    items: StackBuffer<T>,
    waiting_not_empty: usize,
    waiting_not_full: usize,
}

#[derive(Debug)]
pub struct LifoQueue<T> {
    not_empty: Condvar,
    not_full: Condvar,
    buffer: Mutex<Stack<T>>,
}

impl<T> LifoQueue<T> {
    pub fn new(capacity: usize) -> LifoQueue<T> {
        LifoQueue {
            not_empty: Condvar::new(),
            not_full: Condvar::new(),
            buffer: Mutex::new(Stack {
                items: StackBuffer::new(capacity),
                waiting_not_empty: 0,
                waiting_not_full: 0,
            }),
        }
    }

    pub fn try_push(&self, x: T) -> Option<T> {
        if let Ok(mut guard) = self.buffer.try_lock() {
            let res = guard.items.push(x);
            if res.is_none() {
                let waiter = guard.waiting_not_empty > 0;
                drop(guard);
                if waiter {
                    self.not_empty.notify_one();
                }
            }
            return res;
        }
        Some(x)
    }

    pub fn push(&self, x: T) {
        let mut guard = zlock!(self.buffer);
        loop {
            if !guard.items.is_full() {
                guard.items.push(x);
                let waiter = guard.waiting_not_empty > 0;
                drop(guard);
                if waiter {
                    self.not_empty.notify_one();
                }
                return;
            }
            guard.waiting_not_full += 1;
            guard = self.not_full.wait(guard).unwrap();
            guard.waiting_not_full -= 1;
        }
    }

    pub fn try_pull(&self) -> Option<T> {
        if let Ok(mut guard) = self.buffer.try_lock() {
            if let Some(e) = guard.items.pop() {
                let waiter = guard.waiting_not_full > 0;
                drop(guard);
                if waiter {
                    self.not_full.notify_one();
                }
                return Some(e);
            }
        }
        None
    }

    pub fn pull(&self) -> T {
        let mut guard = zlock!(self.buffer);
        loop {
            if let Some(e) = guard.items.pop() {
                let waiter = guard.waiting_not_full > 0;
                drop(guard);
                if waiter {
                    self.not_full.notify_one();
                }
                return e;
            }
            guard.waiting_not_empty += 1;
            guard = self.not_empty.wait(guard).unwrap();
            guard.waiting_not_empty -= 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use std::{sync::Arc, thread, time::Duration};

    use super::LifoQueue;

    #[test]
    fn a_waiting_puller_is_woken_by_a_push_and_a_waiting_pusher_by_a_pull() {
        let q = Arc::new(LifoQueue::new(1));
        let puller = {
            let q = q.clone();
            thread::spawn(move || q.pull())
        };
        while q.buffer.lock().unwrap().waiting_not_empty == 0 {
            thread::sleep(Duration::from_millis(1));
        }
        q.push(7u32);
        assert_eq!(puller.join().unwrap(), 7);

        q.push(1);
        let pusher = {
            let q = q.clone();
            thread::spawn(move || q.push(2))
        };
        while q.buffer.lock().unwrap().waiting_not_full == 0 {
            thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(q.try_pull(), Some(1));
        pusher.join().unwrap();
        assert_eq!(q.pull(), 2);
    }
}
