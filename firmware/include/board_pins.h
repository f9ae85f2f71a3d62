/*
 * board_pins.h - how the Arduino Mega ADK (ATmega2560) is wired to the VSCMG hardware.
 *
 * Shared by the firmware and the simavr harness (plain macros, no AVR headers), so the emulated wiring is
 * the wiring on the bench. Arduino pin names in brackets.
 *
 * Pulse outputs: channel order gimbal 0, rotor 0, gimbal 1, rotor 1, ... (as RawPulses and Telemetry).
 * Each channel is a hardware output-compare pin of a 16-bit timer in fast-PWM mode 14 (TOP = ICRn,
 * prescaler 8: 0.5 us ticks), so pulse widths are exact to the tick and keep running if the CPU hangs.
 * All four timers share one frame period and start together, so every channel rises at the same instant.
 *   ch 0 OC1A PB5 [D11]   ch 1 OC1B PB6 [D12]   ch 2 OC1C PB7 [D13]
 *   ch 3 OC3A PE3 [D5]    ch 4 OC3B PE4 [D2]    ch 5 OC3C PE5 [D3]
 *   ch 6 OC4A PH3 [D6]    ch 7 OC4B PH4 [D7]    ch 8 OC4C PH5 [D8]
 *   ch 9 OC5A PL3 [D46]   ch10 OC5B PL4 [D45]   ch11 OC5C PL5 [D44]
 * Twelve hardware channels: up to 6 VSCMG units. With 4 units or fewer, Timer5 is free and drives the
 * optional PPM-sum train (8 channels, 22.5 ms frame, 300 us marks) on OC5B PL4 [D45] instead.
 *
 * Analog inputs (internal 2.56 V reference, 10 bits):
 *   ADC0 PF0 [A0] battery voltage through a 70k/10k divider (x8: 20.48 V full scale)
 *   ADC1 PF1 [A1] battery current, shunt amplifier 100 mV/A (25.6 A full scale)
 *   ADC2 PF2 [A2] UBEC rail voltage through a 15k/10k divider (x2.5: 6.4 V full scale)
 *   ADC3 PF3 [A3] UBEC current, shunt amplifier 400 mV/A (6.4 A full scale)
 *
 * ESC supply cut output: PA0 [D22], active high, low at reset (the MCU's pins are inputs until set, so a
 * pull-down keeps the gate off). Wired to a relay or MOSFET in the rotor ESCs' battery lead that opens
 * while the pin is high; the ESC endpoint procedure holds it high for EscCalibrate.supply_off_ms to
 * power-cycle the ESCs (only if the EEPROM says it is wired: esc_supply_switch; otherwise the board asks
 * the operator to connect the supply). A reset never cuts the ESCs' supply.
 *
 * Watchdog self-test input: PK7 [A15], internal pull-up. Pulling it low (a jumper or button to GND)
 * after boot stops the main loop, so the bench can prove the watchdog resets the board and that the
 * host sees WATCHDOG as the reset cause. Only a high-to-low change seen after boot counts, so a jumper
 * left in place cannot hold the board in a reset loop.
 *
 * USB host (the Mega ADK's on-board MAX3421E, on the ATmega2560's SPI; firmware/src/spi.c):
 *   SCK PB1 [D52], MOSI PB2 [D51], MISO PB3 [D50]  the hardware SPI (mode 0, MSB first, fosc/2 = 8 MHz;
 *                                                   the chip takes up to 26 MHz)
 *   SS  PB0 [D53]  the MAX3421E's chip select, active low (also keeps the SPI a master: an SS pin left an
 *                  input and pulled low would drop the SPI into slave mode)
 *   INT PE6 [-]    the MAX3421E's INT output, level mode, active low (PINCTL.INTLEVEL; the chip drives
 *                  it open-drain, so the firmware enables the pull-up). Not broken out to a header.
 *   RES PJ2 [-]    the MAX3421E's RES input, active low: held high to run the chip. Not broken out.
 * Verified against the USB Host Shield 2.0 library (felis/USB_Host_Shield_2.0): UsbCore.h selects
 * `MAX3421e<P53, P54>` for BOARD_MEGA_ADK (which avrpins.h defines for ARDUINO_AVR_ADK on an
 * ATmega2560), avrpins.h maps P53 = Pb0, and under BOARD_MEGA_ADK "P54 Pe6 // INT on Arduino ADK" and
 * "P55 Pj2 // MAX_RESET on Arduino ADK"; usbhost.h's MAX3421e constructor drives P55 as an output, high,
 * on the ADK, and its SPI typedef for the ATmega2560 is SPi<Pb1, Pb2, Pb3, Pb0> (SCK, MOSI, MISO, SS).
 * None of these pins is a pulse channel (those are PB5-7, PE3-5, PH3-5, PL3-5).
 */
#ifndef BOARD_PINS_H
#define BOARD_PINS_H

#define PULSE_CHANNELS_HW 12u /* output-compare channels wired */

/* Port letter and bit of each pulse channel, for the harness (the firmware uses the timer registers). */
#define PULSE_PIN_PORTS "BBBEEEHHHLLL"
#define PULSE_PIN_BITS {5, 6, 7, 3, 4, 5, 3, 4, 5, 3, 4, 5}
#define PPM_PIN_INDEX 10u /* the PPM train shares the recorder's pin 10 (OC5B PL4) */

#define ADC_REF_MV 2560u
#define ADC_FULL_SCALE 1024u
#define ADC_CH_BATTERY_V 0u
#define ADC_CH_BATTERY_I 1u
#define ADC_CH_UBEC_V 2u
#define ADC_CH_UBEC_I 3u
#define BATTERY_DIVIDER_NUM 8u /* pin voltage = battery / 8 */
#define BATTERY_DIVIDER_DEN 1u
#define UBEC_DIVIDER_NUM 5u /* pin voltage = rail * 2 / 5 */
#define UBEC_DIVIDER_DEN 2u
#define BATTERY_I_MV_PER_A 100u
#define UBEC_I_MV_PER_A 400u

#define SELFTEST_PIN_PORT 'K'
#define SELFTEST_PIN_BIT 7

#define ESC_SUPPLY_PIN_PORT 'A'
#define ESC_SUPPLY_PIN_BIT 0

/* The MAX3421E USB host controller (see above): port letter and bit of each line. */
#define USB_SS_PIN_PORT 'B'
#define USB_SS_PIN_BIT 0
#define USB_SCK_PIN_BIT 1 /* port B */
#define USB_MOSI_PIN_BIT 2 /* port B */
#define USB_MISO_PIN_BIT 3 /* port B */
#define USB_INT_PIN_PORT 'E'
#define USB_INT_PIN_BIT 6
#define USB_RES_PIN_PORT 'J'
#define USB_RES_PIN_BIT 2

#endif /* BOARD_PINS_H */
