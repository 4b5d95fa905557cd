//! Auto-detection picks ESP32 USB-UART bridges, then Bluetooth SPP nodes.
use telextiles_roller::{pick_port, RollerError};
use tokio_serial::{SerialPortInfo, SerialPortType, UsbPortInfo};

fn usb(name: &str, vid: u16, pid: u16) -> SerialPortInfo {
    SerialPortInfo {
        port_name: name.into(),
        port_type: SerialPortType::UsbPort(UsbPortInfo {
            vid,
            pid,
            serial_number: None,
            manufacturer: None,
            product: None,
        }),
    }
}

fn other(name: &str) -> SerialPortInfo {
    SerialPortInfo {
        port_name: name.into(),
        port_type: SerialPortType::Unknown,
    }
}

#[test]
fn known_usb_bridges_win_in_name_order() {
    let ports = [
        other("/dev/ttyS0"),
        usb("/dev/ttyUSB3", 0x1a86, 0x7523), // CH340
        usb("/dev/ttyACM0", 0x2341, 0x0043), // an Arduino: not ours
        usb("/dev/ttyUSB1", 0x10c4, 0xea60), // CP210x
    ];
    let nodes = vec!["/dev/rfcomm0".to_string()];
    assert_eq!(pick_port(&ports, &nodes).unwrap(), "/dev/ttyUSB1");
    let ftdi = [usb("/dev/ttyUSB0", 0x0403, 0x6001)];
    assert_eq!(pick_port(&ftdi, &[]).unwrap(), "/dev/ttyUSB0");
}

#[test]
fn rfcomm_is_the_fallback_and_nothing_is_a_clear_error() {
    let ports = [other("/dev/ttyS0"), usb("/dev/ttyACM0", 0x2341, 0x0043)];
    let nodes: Vec<String> = ["/dev/null", "/dev/rfcomm2", "/dev/rfcomm1", "/dev/ttyS0"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert_eq!(pick_port(&ports, &nodes).unwrap(), "/dev/rfcomm1");
    let err = pick_port(&ports, &["/dev/null".to_string()]).unwrap_err();
    assert!(matches!(err, RollerError::NotFound { .. }));
    let msg = err.to_string();
    assert!(
        msg.contains("10c4:ea60") && msg.contains("1a86:7523") && msg.contains("0403:6001"),
        "{msg}"
    );
    assert!(msg.contains("/dev/rfcomm"), "{msg}");
}
