//! ESP32-WROOM-32 + A4988 binding of the roller firmware core.
//!
//! Pins (change the three `GPIO` lines below for another board):
//!
//! | signal | ESP32 | A4988 |
//! |---|---|---|
//! | STEP | GPIO26 | STEP |
//! | DIR | GPIO25 | DIR |
//! | EN | GPIO27 | /ENABLE (active low) |
//! | - | 3V3 | MS1, MS2, MS3 high (1/16 microstepping) |
//! | link | UART0 (USB-UART bridge) or, with `--features bt-hc05`, UART2 GPIO16/17 to an HC-05 |
//!
//! All logic is in `roller_firmware::Roller`; this loop only moves bytes and
//! turns `step()` results into pulses. The core has no clock: we pass the
//! microsecond timer in.
#![no_std]
#![no_main]

use esp_hal::delay::Delay;
use esp_hal::gpio::{Level, Output, OutputConfig};
use esp_hal::main;
use esp_hal::time::Instant;
use esp_hal::uart::{Config as UartConfig, Uart};
use esp_println as _;
use roller_firmware::{Config, Roller};

use esp_backtrace as _;

esp_bootloader_esp_idf::esp_app_desc!();

#[main]
fn main() -> ! {
    let p = esp_hal::init(esp_hal::Config::default());
    // `telextiles-proto` links `alloc`; the firmware core never allocates.
    esp_alloc::heap_allocator!(size: 4 * 1024);

    let mut step = Output::new(p.GPIO26, Level::Low, OutputConfig::default());
    let mut dir = Output::new(p.GPIO25, Level::Low, OutputConfig::default());
    // A4988 /ENABLE: high = coils off. The core starts disabled.
    let mut en = Output::new(p.GPIO27, Level::High, OutputConfig::default());

    let uart_cfg = UartConfig::default().with_baudrate(115_200);
    #[cfg(not(feature = "bt-hc05"))]
    let mut uart = Uart::new(p.UART0, uart_cfg)
        .expect("UART0 config")
        .with_rx(p.GPIO3)
        .with_tx(p.GPIO1);
    #[cfg(feature = "bt-hc05")]
    let mut uart = Uart::new(p.UART2, uart_cfg)
        .expect("UART2 config")
        .with_rx(p.GPIO16)
        .with_tx(p.GPIO17);

    let delay = Delay::new();
    let mut fw = Roller::new(Config::default());
    let mut rx = [0u8; 64];
    let mut tx = [0u8; 128];
    let mut last_dir = 0i8;

    loop {
        let now = Instant::now().duration_since_epoch().as_micros();

        if uart.read_ready() {
            if let Ok(n) = uart.read_buffered(&mut rx) {
                fw.receive(&rx[..n], now);
            }
        }

        if let Some(d) = fw.step(now) {
            if d != last_dir {
                dir.set_level(if d > 0 { Level::High } else { Level::Low });
                delay.delay_micros(1); // A4988: DIR setup >= 200 ns
                last_dir = d;
            }
            step.set_high();
            delay.delay_micros(2); // A4988: STEP high >= 1 us
            step.set_low();
        }

        fw.service(now);
        en.set_level(if fw.motor_enabled() { Level::Low } else { Level::High });

        let n = fw.take_output(&mut tx);
        if n > 0 {
            // The UART's 128-byte TX FIFO takes a few frames without
            // blocking (replies are 7..=29 bytes, status every 100 ms), so
            // writing never delays a step.
            let _ = uart.write(&tx[..n]);
        }
    }
}
