//! The one shape every board has: what `board::init` hands the tasks, and the two services
//! a board implements its own way (the watchdog, the coefficient store). The boards differ
//! only in the types behind `board::FluxPort`, `board::Watchdog`, `board::CoefStore`.

use embassy_stm32::usart::{BufferedUartRx, BufferedUartTx};

use crate::board;
use crate::store;

/// What a board gives the firmware at boot.
pub struct Board {
    pub scalar: BufferedUartRx<'static>,
    pub flux: board::FluxPort,
    pub gps: BufferedUartRx<'static>,
    pub out_tx: BufferedUartTx<'static>,
    pub out_rx: BufferedUartRx<'static>,
    pub watchdog: board::Watchdog,
    pub store: board::CoefStore,
}

/// A watchdog that resets the board unless fed within `crate::WATCHDOG_TIMEOUT_US`.
pub trait Watchdog {
    /// Starts it (cannot be stopped).
    fn unleash(&mut self);
    fn feed(&mut self);
}

#[derive(Debug, defmt::Format)]
pub struct StoreError;

/// The coefficient store's bytes ([`store::LEN`], layout in `store.rs`).
pub trait CoefStore {
    fn read(&mut self, raw: &mut [u8; store::LEN]) -> Result<(), StoreError>;
    fn write(&mut self, raw: &[u8; store::LEN]) -> Result<(), StoreError>;
}
