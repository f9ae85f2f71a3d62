/*
 * power.c - the board's power as its analog inputs see it, and the MCU's brown-out detector.
 *
 * Battery: an open-circuit voltage (--battery, default a full 3S LiPo) minus scheduled sags (ramped,
 * like firmware_sim's faults.sag) minus its internal resistance times the load current. Load: each
 * rotor ESC draws idle + full * throttle^3 from the pack, throttle read from the pulses the firmware
 * actually puts out (1000..2000 us), nothing while the firmware cuts the ESCs' supply; the UBEC feeds the electronics and the gimbal servos from the pack
 * at 85 % efficiency. The UBEC rail follows its set voltage until the pack drops within its dropout.
 * These four quantities reach the firmware through ADC0..3 scaled as on the board (board_pins.h).
 *
 * With the "power" command the caller's battery model (firmware_sim's, driven by the simulated world's
 * units) sets the four quantities instead, and this model stands aside: one battery, not two.
 *
 * Brown-out: while the rail is under the BODLEVEL (4.3 V) the MCU is held in reset and runs no
 * instructions; once it is back above the release level it starts with BORF set in MCUSR.
 */
#include <math.h>

#include <avr_adc.h>
#include <sim_io.h>
#include <sim_irq.h>

#include "../include/board_pins.h"
#include "harness.h"

#define UBEC_EFFICIENCY 0.85
#define ESC_IDLE_A 0.05
#define SERVO_A 0.02
#define PULSE_STALE_S 0.1 /* a channel with no pulse for this long draws nothing */

static avr_irq_t *adc_irq[4];

void power_init(harness_t *h)
{
    for (int ch = 0; ch < 4; ch++) {
        adc_irq[ch] = avr_io_getirq(h->avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + ch);
        h->pin_mv[ch] = 0xFFFFFFFFu;
    }
    h->battery_v = h->battery_ocv_v;
    power_update(h);
}

int power_add_sag(harness_t *h, double drop_v, double ramp_s, double duration_s, double at_s)
{
    if (h->n_sags == MAX_SAGS || !(drop_v >= 0) || !(ramp_s >= 0) || !(duration_s > 0))
        return -1;
    h->sags[h->n_sags++] = (sag_t){at_s, drop_v, ramp_s, duration_s};
    return 0;
}

static double sag_volts(const harness_t *h, double t)
{
    double v = 0;
    for (int i = 0; i < h->n_sags; i++) {
        const sag_t *s = &h->sags[i];
        if (t < s->start_s || t >= s->start_s + s->duration_s)
            continue;
        double k = s->ramp_s <= 0 ? 1.0 : fmin((t - s->start_s) / s->ramp_s, 1.0);
        v += k * s->drop_v;
    }
    return v;
}

static void set_pin(harness_t *h, unsigned ch, double mv)
{
    uint32_t v = mv <= 0 ? 0 : (mv >= 5000 ? 5000 : (uint32_t)lround(mv));
    if (v != h->pin_mv[ch]) {
        h->pin_mv[ch] = v;
        avr_raise_irq(adc_irq[ch], v);
    }
}

void power_update(harness_t *h)
{
    uint64_t now = harness_now(h);
    double t = (double)now / h->freq;
    double rotor_a = 0, servo_a = 0;
    for (unsigned pin = 0; pin < PULSE_CHANNELS_HW; pin++) {
        if (h->held || h->pulse_us[pin] == 0 || (double)(now - h->rise[pin]) / h->freq > PULSE_STALE_S)
            continue;
        if (pin % 2) {
            if (h->esc_supply_cut)
                continue; /* the ESCs' supply is cut */
            double thr = fmin(fmax((h->pulse_us[pin] - 1000.0) / 1000.0, 0.0), 1.0);
            rotor_a += ESC_IDLE_A + h->rotor_full_a * thr * thr * thr;
        } else {
            servo_a += SERVO_A;
        }
    }
    if (h->power_external) {
        h->battery_v = h->ext_battery_v;
        h->battery_a = h->ext_battery_a;
        h->ubec_v = h->ext_ubec_v;
        h->ubec_a = h->ext_ubec_a;
    } else {
        double ocv = fmax(h->battery_ocv_v - sag_volts(h, t), 0.0);
        double rail = fmin(h->ubec_set_v, fmax(h->battery_v - h->ubec_dropout_v, 0.0));
        double ubec_a = rail > 0 ? h->electronics_a + servo_a : 0.0;
        /* constant-power loads at the last voltage; one fixed-point step per slice converges in a few ms */
        double v = h->battery_v > 0.5 ? h->battery_v : ocv;
        double amps = rotor_a + (rail * ubec_a / UBEC_EFFICIENCY) / v;
        h->battery_v = fmax(ocv - h->battery_ohm * amps, 0.0);
        h->battery_a = h->battery_v > 0 ? amps : 0.0;
        h->ubec_v = fmin(h->ubec_set_v, fmax(h->battery_v - h->ubec_dropout_v, 0.0));
        h->ubec_a = ubec_a;
    }
    set_pin(h, ADC_CH_BATTERY_V, h->battery_v * 1000.0 * BATTERY_DIVIDER_DEN / BATTERY_DIVIDER_NUM);
    set_pin(h, ADC_CH_BATTERY_I, h->battery_a * BATTERY_I_MV_PER_A);
    set_pin(h, ADC_CH_UBEC_V, h->ubec_v * 1000.0 * UBEC_DIVIDER_DEN / UBEC_DIVIDER_NUM);
    set_pin(h, ADC_CH_UBEC_I, h->ubec_a * UBEC_I_MV_PER_A);

    if (!h->held && h->ubec_v < h->bod_v) {
        record_line(h, "B %llu 1\n", (unsigned long long)now);
        h->held = 1;
        harness_reset(h, -1); /* outputs off, nothing runs until the rail recovers */
    } else if (h->held && h->ubec_v >= h->bod_release_v) {
        record_line(h, "B %llu 0\n", (unsigned long long)now);
        h->held = 0;
        harness_reset(h, CAUSE_BROWN_OUT);
    }
}
