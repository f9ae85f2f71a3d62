/*
 * pulses.h - servo pulse outputs from the 16-bit timers (board_pins.h) and the optional PPM-sum train.
 *
 * Every channel is an output-compare pin in fast-PWM mode 14: TOP = ICRn sets the frame period, OCRnx
 * the pulse width, both in 0.5 us ticks. A channel is set to a fine width (1/512 us, what a calibration
 * map asks for; protocol/pulse_widths.py): the Timer1 overflow interrupt, at each frame start, writes
 * the frame's whole ticks and carries the fraction of a tick to the next frame (sigma-delta), so the
 * mean width is the fine width. The hardware double-buffers OCRnx and loads it at the start of the next
 * frame, so a new width never cuts a pulse short, and the outputs go on at their last widths whatever
 * the main loop does (a hung main loop leaves them at their last targets, as the watchdog test shows).
 *
 * PPM-sum (4 units or fewer): Timer5 in fast-PWM mode 15 on OC5B, one timer period per channel (the
 * time between rising edges is the channel's width, 700..2300 us), 300 us marks, then the sync gap to
 * 22.5 ms; its overflow interrupt loads the period after next (OCR5A is double-buffered too).
 */
#ifndef PULSES_H
#define PULSES_H

#include <stdint.h>

#define PULSE_FRACTION_BITS 8u /* a fine width: whole 0.5 us ticks << 8 | 256ths of a tick */
#define PULSE_FINE_PER_US 512u

void pulses_init(float frame_rate_hz, uint8_t n_channels, uint8_t ppm);
/* Fine width of channel `ch` from the next frame on (1/512 us, 500..2500 us), or 0 for no pulse; a
 * channel held by pulses_hold keeps its held width. */
void pulses_set(uint8_t ch, uint32_t width_fine);
/* The channels in `mask` (bit ch) to `width_us` from the next frame on, then held there (pulses_set leaves
 * them alone) until pulses_release: the link watchdog's stop, from the tick interrupt. */
void pulses_hold(uint16_t mask, uint16_t width_us);
void pulses_release(uint16_t mask);
uint32_t pulses_get(uint8_t ch);
/* The whole us a fine width is reported as (Telemetry.pulses_us; half up). */
uint16_t pulses_reported_us(uint32_t width_fine);
/* 1 once per frame start since the last call (the main loop's frame clock). */
uint8_t pulses_frame_started(void);
/* The frame period actually generated (us), from the timer's TOP. */
float pulses_period_s(void);
/* Low time (0.5 us ticks) every frame keeps after its pulse: a width that reaches the frame's end (a
 * 2500 us pulse in a 490 Hz frame of 2041 us) leaves OCRnx at or past TOP, and fast-PWM mode 14 then
 * never clears the pin: a constant high, no pulse at all to a servo or ESC. */
#define PULSE_GAP_TICKS 40u /* 20 us; firmware_sim/board/config.py PULSE_GAP_US */
/* The longest fine width the frame holds: its period less PULSE_GAP_TICKS, whatever the dither carries. */
uint32_t pulses_longest_fine(void);

#endif /* PULSES_H */
