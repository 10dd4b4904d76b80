//! Graceful shutdown, after mini-redis: one sender flips a watch channel;
//! every task holds a [`Shutdown`] and stops taking new work when it fires.

use tokio::sync::watch;

/// Starts a shutdown; dropping it does not.
#[derive(Debug)]
pub struct ShutdownTrigger(watch::Sender<bool>);

/// Remembers whether shutdown was signalled and waits for it.
#[derive(Debug, Clone)]
pub struct Shutdown(watch::Receiver<bool>);

/// A new trigger and its first listener.
pub fn channel() -> (ShutdownTrigger, Shutdown) {
    let (tx, rx) = watch::channel(false);
    (ShutdownTrigger(tx), Shutdown(rx))
}

impl ShutdownTrigger {
    pub fn trigger(&self) {
        self.0.send_replace(true);
    }

    pub fn subscribe(&self) -> Shutdown {
        Shutdown(self.0.subscribe())
    }
}

impl Shutdown {
    pub fn is_shutdown(&self) -> bool {
        *self.0.borrow()
    }

    /// Resolves once shutdown is signalled (at once if it already was).
    pub async fn wait(&mut self) {
        // An error means the trigger is gone, which also ends the server.
        let _ = self.0.wait_for(|v| *v).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn every_listener_sees_the_trigger() {
        let (t, mut a) = channel();
        let mut b = t.subscribe();
        assert!(!a.is_shutdown());
        t.trigger();
        a.wait().await;
        b.wait().await;
        assert!(a.is_shutdown() && b.is_shutdown());
    }
}
