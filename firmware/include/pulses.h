/*
 * pulses.h - servo pulse outputs from the 16-bit timers (board_pins.h) and the optional PPM-sum train.
 *
 * Every channel is an output-compare pin in fast-PWM mode 14: TOP = ICRn sets the frame period, OCRnx
 * the pulse width, both in 0.5 us ticks. The hardware double-buffers OCRnx and loads it at the start
 * of the next frame, so a new width never cuts a pulse short, and the outputs go on at their last
 * widths whatever the CPU does (a hung main loop leaves them frozen, as the watchdog test shows).
 *
 * PPM-sum (4 units or fewer): Timer5 in fast-PWM mode 15 on OC5B, one timer period per channel (the
 * time between rising edges is the channel's width, 700..2300 us), 300 us marks, then the sync gap to
 * 22.5 ms; its overflow interrupt loads the period after next (OCR5A is double-buffered too).
 */
#ifndef PULSES_H
#define PULSES_H

#include <stdint.h>

void pulses_init(float frame_rate_hz, uint8_t n_channels, uint8_t ppm);
/* Width of channel `ch` from the next frame on (us, 500..2500), or 0 for no pulse at all; a channel
 * held by pulses_hold keeps its held width. */
void pulses_set(uint8_t ch, uint16_t width_us);
/* The channels in `mask` (bit ch) to `width_us` at once, then held there (pulses_set leaves them alone)
 * until pulses_release: the link watchdog's stop, from the tick interrupt. */
void pulses_hold(uint16_t mask, uint16_t width_us);
void pulses_release(uint16_t mask);
uint16_t pulses_get(uint8_t ch);
/* 1 once per frame start since the last call (the main loop's frame clock). */
uint8_t pulses_frame_started(void);
/* The frame period actually generated (us), from the timer's TOP. */
float pulses_period_s(void);

#endif /* PULSES_H */
