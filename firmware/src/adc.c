/* adc.c - background sampling of the power inputs (see adc.h). */
#include "adc.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#include "board_pins.h"

#define CHANNELS 4u
#define REF_BITS (_BV(REFS1) | _BV(REFS0)) /* internal 2.56 V reference */

static volatile uint32_t sums[CHANNELS]; /* of completed rounds only */
static volatile uint16_t samples;
static uint16_t round_counts[CHANNELS]; /* the round being converted (ISR only) */
static volatile uint8_t channel, busy;

static void select(uint8_t ch)
{
    ADMUX = (uint8_t)(REF_BITS | (ch & 7u));
    ADCSRB &= (uint8_t)~_BV(MUX5);
}

static uint16_t blocking(uint8_t ch)
{
    select(ch);
    ADCSRA |= _BV(ADSC);
    while (ADCSRA & _BV(ADSC))
        ;
    return ADC;
}

static uint32_t pin_mv(uint32_t counts_sum, uint16_t n)
{
    return counts_sum * ADC_REF_MV / ADC_FULL_SCALE / n;
}

static void scale(const uint32_t *s, uint16_t n, power_reading_t *out)
{
    uint32_t v;
    v = pin_mv(s[ADC_CH_BATTERY_V], n) * BATTERY_DIVIDER_NUM / BATTERY_DIVIDER_DEN;
    out->battery_mv = (uint16_t)(v > 0xFFFFu ? 0xFFFFu : v);
    v = pin_mv(s[ADC_CH_BATTERY_I], n) * 1000UL / BATTERY_I_MV_PER_A;
    out->battery_ma = (uint16_t)(v > 0xFFFFu ? 0xFFFFu : v);
    v = pin_mv(s[ADC_CH_UBEC_V], n) * UBEC_DIVIDER_NUM / UBEC_DIVIDER_DEN;
    out->ubec_mv = (uint16_t)(v > 0xFFFFu ? 0xFFFFu : v);
    v = pin_mv(s[ADC_CH_UBEC_I], n) * 1000UL / UBEC_I_MV_PER_A;
    out->ubec_ma = (uint16_t)(v > 0xFFFFu ? 0xFFFFu : v);
}

void adc_init(power_reading_t *first)
{
    DIDR0 = 0x0F;                                              /* digital input buffers off on ADC0..3 */
    ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0); /* 125 kHz ADC clock */
    uint32_t s[CHANNELS];
    blocking(0); /* the first conversion after enabling is the long one: discard it */
    for (uint8_t ch = 0; ch < CHANNELS; ch++)
        s[ch] = blocking(ch);
    scale(s, 1, first);
    ADCSRA |= _BV(ADIE);
}

void adc_start_round(void)
{
    if (busy)
        return; /* the previous round is still converting */
    busy = 1;
    channel = 0;
    select(0);
    ADCSRA |= _BV(ADSC);
}

ISR(ADC_vect)
{
    round_counts[channel] = ADC;
    if (++channel < CHANNELS) {
        select(channel);
        ADCSRA |= _BV(ADSC);
        return;
    }
    for (uint8_t ch = 0; ch < CHANNELS; ch++)
        sums[ch] += round_counts[ch];
    samples++;
    busy = 0;
}

uint8_t adc_take(power_reading_t *out)
{
    uint32_t s[CHANNELS];
    uint16_t n;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        n = samples;
        for (uint8_t ch = 0; ch < CHANNELS; ch++) {
            s[ch] = sums[ch];
            sums[ch] = 0;
        }
        samples = 0;
    }
    if (!n)
        return 0;
    scale(s, n, out);
    return 1;
}
