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
