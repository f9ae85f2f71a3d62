/*
 * adc.h - the power inputs (board_pins.h: ADC0..3) sampled in the background.
 *
 * Each 1 kHz tick starts one round of conversions of the four channels (interrupt-driven, ~0.4 ms);
 * the results are summed until the main loop takes them, so every reading the power manager gets is
 * the mean of all samples since the previous one (5 per channel at the default 5 ms update period).
 */
#ifndef ADC_H
#define ADC_H

#include <stdint.h>

#include "board_pins.h"

/* The highest UBEC rail voltage the ADC can report (mV): the top count (1023 of 1024) through the rail's
 * divider, truncated as adc.c's scale() does (6392 mV). A level above it is never measured: the brown-out
 * release is bounded by it (config.c), or the board would stay in BROWN_OUT for good. */
#define ADC_UBEC_MAX_MV \
    ((uint32_t)(ADC_FULL_SCALE - 1u) * ADC_REF_MV / ADC_FULL_SCALE * UBEC_DIVIDER_NUM / UBEC_DIVIDER_DEN)

/* The highest battery voltage the ADC can report (mV), the same way through the pack's divider (20 456 mV):
 * a pack full above it reads as less than it holds, its cells' stage wrong from power-on (config.c bounds
 * the cells by it, as firmware_sim/avr/eeprom.py's check_hardware does). */
#define ADC_BATTERY_MAX_MV \
    ((uint32_t)(ADC_FULL_SCALE - 1u) * ADC_REF_MV / ADC_FULL_SCALE * BATTERY_DIVIDER_NUM / BATTERY_DIVIDER_DEN)

typedef struct {
    uint16_t battery_mv; /* pack voltage */
    uint16_t battery_ma; /* pack current */
    uint16_t ubec_mv;    /* 5 V rail */
    uint16_t ubec_ma;    /* rail current */
} power_reading_t;

/* Configure the ADC and take one blocking reading of every channel (so boot has a first reading). */
void adc_init(power_reading_t *first);
/* Start a round of conversions (called from the tick). */
void adc_start_round(void);
/* The mean of the samples since the last call, scaled to physical units: 1, or 0 if there were none. */
uint8_t adc_take(power_reading_t *out);

#endif /* ADC_H */
