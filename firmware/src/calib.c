/*
 * calib.c - calibration sets: validation and evaluation (see calib.h), line by line after
 * protocol/calibration/cubic.py (MonotoneCubic.evaluate/solve, _solve_interval) and maps.py, in float32.
 */
#include "calib.h"

#include <math.h>
#include <string.h>

#include "crc16.h"
#include "flash.h"
#include "protocol_gen.h"

#define SOLVE_MAX_ITER 20
#define SOLVE_TOL_T 1e-6f
#define SLOPE_TOLERANCE 1e-5f
#define MAX_KV 1.0e4f
#define OFF_LOW 4
#define OFF_HIGH 8
#define OFF_DEADBAND 12
#define OFF_KV 16
#define OFF_HOLD 20
#define OFF_COUNTS 24

typedef struct {
    const uint8_t *knots; /* n knots of 12 bytes: x, y, m */
    uint8_t n;
} table_t;

static float f32_at(const uint8_t *p)
{
    float v;
    __builtin_memcpy(&v, p, 4); /* both ends are little-endian IEEE-754; inlined */
    return v;
}

static float kx(const table_t *t, uint8_t k) { return f32_at(t->knots + CAL_KNOT_SIZE * k); }
static float ky(const table_t *t, uint8_t k) { return f32_at(t->knots + CAL_KNOT_SIZE * k + 4); }
static float km(const table_t *t, uint8_t k) { return f32_at(t->knots + CAL_KNOT_SIZE * k + 8); }

static table_t table_of(const uint8_t *set, uint8_t which)
{
    uint16_t offset = CAL_HEADER_SIZE;
    for (uint8_t i = 0; i < which; i++) /* tables follow each other in order */
        offset = (uint16_t)(offset + CAL_KNOT_SIZE * set[OFF_COUNTS + i]);
    table_t t = {set + offset, set[OFF_COUNTS + which]};
    return t;
}

static cal_conv_t conv(float value, uint8_t clamp)
{
    cal_conv_t c = {value, clamp};
    return c;
}

static int rising(const table_t *t) { return ky(t, (uint8_t)(t->n - 1)) > ky(t, 0); }

/*
 * The factor interval k's values (y, slopes) are taken at: 1, or a power of two that brings an interval
 * whose values lie beyond 2^64 (or all below 2^-64) into the middle of float32's range. The reference works
 * in double; float32 overflowed on a table that is valid but spans most of its range (y from -3e38 to 3e38:
 * y1 - y0 and 3 * d infinite, the cubic NaN: a gimbal commanded to angle 0 went to 2000 us), and lost the
 * bits of one whose values are subnormal (a table of +-1e-43 rad: widths 4.5 us off). A power of two
 * scales exactly, so a table of everyday magnitudes computes bit for bit as before.
 */
#define CAL_BIG_VALUE 1.8446744e19f   /* 2^64 */
#define CAL_SMALL_VALUE 5.4210109e-20f /* 2^-64 */

static float interval_scale(const table_t *t, uint8_t k)
{
    float a = fabsf(ky(t, k)), b = fabsf(ky(t, (uint8_t)(k + 1)));
    float top = a > b ? a : b;
    return top >= CAL_BIG_VALUE ? CAL_SMALL_VALUE : (top < CAL_SMALL_VALUE ? CAL_BIG_VALUE : 1.0f);
}

/* (a1, a2, a3) of y = y0 + t*(a1 + t*(a2 + t*a3)) on interval k of width h, all times `scale`. */
static void coefficients(const table_t *t, uint8_t k, float h, float scale, float *a1, float *a2, float *a3)
{
    float d = ky(t, (uint8_t)(k + 1)) * scale - ky(t, k) * scale;
    float hm0 = h * (km(t, k) * scale);
    float hm1 = h * (km(t, (uint8_t)(k + 1)) * scale);
    *a1 = hm0;
    *a2 = 3.0f * d - 2.0f * hm0 - hm1;
    *a3 = hm0 + hm1 - 2.0f * d;
}

static cal_conv_t table_evaluate(const table_t *t, float x)
{
    uint8_t last = (uint8_t)(t->n - 1);
    if (x < kx(t, 0))
        return conv(ky(t, 0), CAL_CLAMP_LOW);
    if (x > kx(t, last))
        return conv(ky(t, last), CAL_CLAMP_HIGH);
    uint8_t k = 0;
    while (k < last - 1 && x >= kx(t, (uint8_t)(k + 1)))
        k++;
    float h = kx(t, (uint8_t)(k + 1)) - kx(t, k);
    float u = (x - kx(t, k)) / h;
    float a1, a2, a3, scale = interval_scale(t, k);
    coefficients(t, k, h, scale, &a1, &a2, &a3);
    float y = (ky(t, k) * scale + u * (a1 + u * (a2 + u * a3))) / scale;
    if (scale != 1.0f) { /* the cubic lies between its ends: rounding must not carry it past F32_MAX */
        float y0 = ky(t, k), y1 = ky(t, (uint8_t)(k + 1));
        float lo = y0 < y1 ? y0 : y1, hi = y0 < y1 ? y1 : y0;
        y = y < lo ? lo : (y > hi ? hi : y);
    }
    return conv(y, CAL_CLAMP_NONE);
}

/* Safeguarded Newton on one monotone interval (cubic.py: _solve_interval). The direction s = +-1 is
 * folded into the coefficients and the target (an exact sign flip), so e and g below are s times the
 * reference's polynomial and derivative, with the same values and the same steps. */
static float solve_interval(float target, float s, float a1, float a2, float a3, float u)
{
    if (s < 0.0f) {
        a1 = -a1;
        a2 = -a2;
        a3 = -a3;
        target = -target;
    }
    const float b2 = 2.0f * a2, b3 = 3.0f * a3;
    float lo = 0.0f, hi = 1.0f;
    for (uint8_t i = 0; i < SOLVE_MAX_ITER; i++) {
        float e = u * (a1 + u * (a2 + u * a3)) - target;
        if (e == 0.0f)
            break;
        if (e > 0.0f)
            hi = u;
        else
            lo = u;
        float g = a1 + u * (b2 + u * b3);
        float un = g > 0.0f ? u - e / g : 0.5f * (lo + hi);
        if (!(lo < un && un < hi))
            un = 0.5f * (lo + hi);
        int done = fabsf(un - u) <= SOLVE_TOL_T;
        u = un;
        if (done)
            break;
    }
    return u;
}

static cal_conv_t table_solve(const table_t *t, float y)
{
    uint8_t last = (uint8_t)(t->n - 1);
    int up = rising(t);
    float lo = up ? ky(t, 0) : ky(t, last), hi = up ? ky(t, last) : ky(t, 0);
    if (y < lo)
        return conv(up ? kx(t, 0) : kx(t, last), CAL_CLAMP_LOW);
    if (y > hi)
        return conv(up ? kx(t, last) : kx(t, 0), CAL_CLAMP_HIGH);
    float s = up ? 1.0f : -1.0f;
    uint8_t k = 0;
    while (k < last - 1 && s * (y - ky(t, (uint8_t)(k + 1))) > 0.0f)
        k++;
    float x0 = kx(t, k);
    float h = kx(t, (uint8_t)(k + 1)) - x0;
    float scale = interval_scale(t, k);
    float y0 = ky(t, k) * scale, target = y * scale - y0;
    float a1, a2, a3;
    coefficients(t, k, h, scale, &a1, &a2, &a3);
    float u = solve_interval(target, s, a1, a2, a3, target / (ky(t, (uint8_t)(k + 1)) * scale - y0));
    return conv(x0 + u * h, CAL_CLAMP_NONE);
}

/* ------------------------------------------------------------------------------------------ maps */
float cal_esc_low_us(const uint8_t *set) { return f32_at(set + OFF_LOW); }
float cal_esc_high_us(const uint8_t *set) { return f32_at(set + OFF_HIGH); }

static cal_conv_t esc_throttle(const uint8_t *set, float p)
{
    float low = cal_esc_low_us(set), high = cal_esc_high_us(set);
    if (p < low)
        return conv(0.0f, CAL_CLAMP_LOW);
    if (p > high)
        return conv(1.0f, CAL_CLAMP_HIGH);
    float start = low + f32_at(set + OFF_DEADBAND);
    if (p <= start)
        return conv(0.0f, CAL_CLAMP_NONE);
    return conv((p - start) / (high - start), CAL_CLAMP_NONE);
}

static float esc_pulse(const uint8_t *set, float tau)
{
    float low = cal_esc_low_us(set), high = cal_esc_high_us(set);
    if (tau <= 0.0f)
        return low;
    if (tau >= 1.0f)
        return high;
    float start = low + f32_at(set + OFF_DEADBAND);
    return start + tau * (high - start);
}

cal_conv_t cal_rotor_speed(const uint8_t *set, float pulse_us, float battery_v)
{
    cal_conv_t tau = esc_throttle(set, pulse_us);
    if (battery_v < CAL_MIN_SUPPLY_V)
        return conv(0.0f, CAL_CLAMP_LOW);
    table_t curve = table_of(set, CAL_TABLE_ROTOR);
    float frac = table_evaluate(&curve, tau.value).value;
    return conv(f32_at(set + OFF_KV) * battery_v * frac, tau.clamp);
}

cal_conv_t cal_rotor_pulse_us(const uint8_t *set, float speed_rad_s, float battery_v)
{
    float low = cal_esc_low_us(set);
    if (speed_rad_s <= 0.0f)
        return conv(low, speed_rad_s < 0.0f ? CAL_CLAMP_LOW : CAL_CLAMP_NONE);
    if (battery_v < CAL_MIN_SUPPLY_V)
        return conv(low, CAL_CLAMP_HIGH);
    float phi = speed_rad_s / (f32_at(set + OFF_KV) * battery_v);
    if (phi <= 0.0f) /* a positive speed so small its fraction underflows float32: the smallest throttle */
        return conv(esc_pulse(set, 1e-30f), CAL_CLAMP_NONE);
    if (phi >= 1.0f)
        return conv(cal_esc_high_us(set), phi > 1.0f ? CAL_CLAMP_HIGH : CAL_CLAMP_NONE);
    table_t curve = table_of(set, CAL_TABLE_ROTOR);
    float tau = table_solve(&curve, phi).value;
    if (tau <= 0.0f) /* a subnormal fraction the float32 solve takes to 0: still a speed, the smallest throttle */
        tau = 1e-30f;
    return conv(esc_pulse(set, tau), CAL_CLAMP_NONE);
}

/* GimbalRateMap: rate 0 in the dead zone [lower's last pulse, upper's first pulse], tables either side. */
cal_conv_t cal_gimbal_pulse_us(const uint8_t *set, float value, uint8_t gimbal_mode)
{
    if (gimbal_mode != GIMBAL_MODE_RATE) {
        table_t angle = table_of(set, CAL_TABLE_ANGLE);
        return table_solve(&angle, value);
    }
    if (value == 0.0f)
        return conv(f32_at(set + OFF_HOLD), CAL_CLAMP_NONE);
    table_t upper = table_of(set, CAL_TABLE_RATE_UPPER);
    if ((value > 0.0f) == (ky(&upper, (uint8_t)(upper.n - 1)) > 0.0f))
        return table_solve(&upper, value);
    table_t lower = table_of(set, CAL_TABLE_RATE_LOWER);
    return table_solve(&lower, value);
}

cal_conv_t cal_gimbal_value(const uint8_t *set, float pulse_us, uint8_t gimbal_mode)
{
    if (gimbal_mode != GIMBAL_MODE_RATE) {
        table_t angle = table_of(set, CAL_TABLE_ANGLE);
        return table_evaluate(&angle, pulse_us);
    }
    table_t lower = table_of(set, CAL_TABLE_RATE_LOWER);
    if (pulse_us < kx(&lower, (uint8_t)(lower.n - 1)))
        return table_evaluate(&lower, pulse_us);
    table_t upper = table_of(set, CAL_TABLE_RATE_UPPER);
    if (pulse_us > kx(&upper, 0))
        return table_evaluate(&upper, pulse_us);
    return conv(0.0f, CAL_CLAMP_NONE);
}

/* ------------------------------------------------------------------------------------------ checks */
static int is_finite32(float v) { return v == v && v - v == 0.0f; }

/* MonotoneCubic.__post_init__: finite numbers, x increasing, not flat end to end, each interval
 * strictly monotone with its knot slopes inside the box that keeps the cubic monotone. */
static cal_status_t check_table(const table_t *t, uint8_t *knot)
{
    for (uint8_t col = 0; col < 3; col++) {
        for (uint8_t k = 0; k < t->n; k++) {
            *knot = k;
            if (!is_finite32(f32_at(t->knots + CAL_KNOT_SIZE * k + 4 * col)))
                return CAL_NOT_FINITE;
        }
    }
    for (uint8_t k = 0; k + 1 < t->n; k++) {
        *knot = (uint8_t)(k + 1);
        if (!(kx(t, k) < kx(t, (uint8_t)(k + 1))))
            return CAL_X_ORDER;
    }
    *knot = 0;
    if (ky(t, (uint8_t)(t->n - 1)) == ky(t, 0))
        return CAL_FLAT;
    int up = rising(t);
    for (uint8_t k = 0; k + 1 < t->n; k++) {
        /* in the interval's scale (interval_scale): an infinite secant would let any slope through */
        float scale = interval_scale(t, k);
        float d = ky(t, (uint8_t)(k + 1)) * scale - ky(t, k) * scale;
        *knot = (uint8_t)(k + 1);
        if (up ? d <= 0.0f : d >= 0.0f)
            return CAL_NOT_MONOTONE;
        float secant = d / (kx(t, (uint8_t)(k + 1)) - kx(t, k));
        for (uint8_t j = k; j <= k + 1; j++) {
            float m = km(t, j);
            *knot = j;
            /* the signs compared, not their product: that underflows to 0 where the reference's does not */
            if ((m < 0.0f && secant > 0.0f) || (m > 0.0f && secant < 0.0f) ||
                fabsf(m) * scale > 3.0f * fabsf(secant) * (1.0f + SLOPE_TOLERANCE))
                return CAL_BAD_SLOPE;
        }
    }
    return CAL_OK;
}

static int pulse_in_range(float us) { return (float)PULSE_MIN_US <= us && us <= (float)PULSE_MAX_US; }

/* maps.py check_pulses: every knot's pulse (x) a board can put out. A conversion clamps to the table's
 * ends, so the widths it commands stay in range; a table beyond it was clamped by to_fine instead (a hold
 * at 10000 us went out as 2500 us: the gimbal at full rate under a rate-0 command). */
static cal_status_t check_table_pulses(const table_t *t, uint8_t *knot)
{
    for (uint8_t k = 0; k < t->n; k++) {
        *knot = k;
        if (!pulse_in_range(kx(t, k)))
            return CAL_BAD_PULSE;
    }
    *knot = 0;
    return CAL_OK;
}

/* GimbalRateMap.__post_init__: the hold pulse and both tables' pulses within 500..2500 us, the lower table
 * ends and the upper starts at rate 0, both turn the same way, and the hold pulse lies in the dead zone
 * between them. */
static cal_status_t check_rate_map(const uint8_t *set, uint8_t *table, uint8_t *knot)
{
    float hold = f32_at(set + OFF_HOLD);
    if (!is_finite32(hold))
        return CAL_NOT_FINITE;
    if (!pulse_in_range(hold))
        return CAL_BAD_PULSE;
    table_t lower = table_of(set, CAL_TABLE_RATE_LOWER), upper = table_of(set, CAL_TABLE_RATE_UPPER);
    *table = CAL_TABLE_RATE_LOWER;
    if (check_table_pulses(&lower, knot) != CAL_OK)
        return CAL_BAD_PULSE;
    *table = CAL_TABLE_RATE_UPPER;
    if (check_table_pulses(&upper, knot) != CAL_OK)
        return CAL_BAD_PULSE;
    *table = CAL_TABLE_RATE_LOWER;
    if (ky(&lower, (uint8_t)(lower.n - 1)) != 0.0f)
        return CAL_BAD_DEAD_ZONE;
    *table = CAL_TABLE_RATE_UPPER;
    if (ky(&upper, 0) != 0.0f || rising(&lower) != rising(&upper))
        return CAL_BAD_DEAD_ZONE;
    *table = 0xFF;
    if (!(kx(&lower, (uint8_t)(lower.n - 1)) <= hold && hold <= kx(&upper, 0)))
        return CAL_BAD_HOLD;
    return CAL_OK;
}

uint16_t cal_set_length(const uint8_t *header)
{
    uint16_t knots = 0;
    for (uint8_t i = 0; i < CAL_TABLES; i++) {
        uint8_t n = header[OFF_COUNTS + i];
        if (n < 2 || n > CAL_MAX_KNOTS)
            return 0;
        knots = (uint16_t)(knots + n);
    }
    return (uint16_t)(CAL_HEADER_SIZE + CAL_KNOT_SIZE * knots + 2u);
}

cal_status_t cal_validate(const uint8_t *set, uint16_t len, uint8_t *table, uint8_t *knot)
{
    uint8_t ignored_table, ignored_knot;
    if (!table)
        table = &ignored_table;
    if (!knot)
        knot = &ignored_knot;
    *table = 0xFF;
    *knot = 0;
    if (len < CAL_HEADER_SIZE + 2u)
        return CAL_TRUNCATED;
    if (set[0] != 'V' || set[1] != 'C')
        return CAL_BAD_MAGIC;
    if (set[2] != 1)
        return CAL_BAD_VERSION;
    if (set[3] != 0)
        return CAL_BAD_RESERVED;
    uint16_t size = cal_set_length(set);
    if (!size)
        return CAL_BAD_COUNT;
    if (len != size)
        return CAL_BAD_LENGTH;
    if (crc16_update(CRC16_INIT, set, (uint16_t)(size - 2u)) != wire_get_u16(set + size - 2u))
        return CAL_BAD_CRC;
    for (uint8_t which = 0; which < CAL_TABLES; which++) {
        table_t t = table_of(set, which);
        *table = which;
        cal_status_t st = check_table(&t, knot);
        if (st != CAL_OK)
            return st;
    }
    *table = 0xFF;
    *knot = 0;
    float low = f32_at(set + OFF_LOW), high = f32_at(set + OFF_HIGH), dead = f32_at(set + OFF_DEADBAND);
    if (!is_finite32(low) || !is_finite32(high) || !is_finite32(dead))
        return CAL_NOT_FINITE;
    if (!((float)PULSE_MIN_US <= low && low < high && high <= (float)PULSE_MAX_US))
        return CAL_BAD_ESC;
    if (!(0.0f <= dead && dead < 0.5f * (high - low)))
        return CAL_BAD_ESC;
    float kv = f32_at(set + OFF_KV);
    if (!is_finite32(kv))
        return CAL_NOT_FINITE;
    if (!(0.0f < kv && kv <= MAX_KV))
        return CAL_BAD_KV;
    table_t rotor = table_of(set, CAL_TABLE_ROTOR);
    *table = CAL_TABLE_ROTOR;
    uint8_t nr = (uint8_t)(rotor.n - 1);
    if (kx(&rotor, 0) != 0.0f || kx(&rotor, nr) != 1.0f || ky(&rotor, 0) != 0.0f || ky(&rotor, nr) != 1.0f)
        return CAL_BAD_CURVE;
    *table = 0xFF;
    cal_status_t st = check_rate_map(set, table, knot);
    if (st != CAL_OK)
        return st;
    table_t angle = table_of(set, CAL_TABLE_ANGLE); /* GimbalAngleMap.__post_init__ */
    *table = CAL_TABLE_ANGLE;
    st = check_table_pulses(&angle, knot);
    if (st == CAL_OK)
        *table = 0xFF;
    return st;
}

void cal_status_text(cal_status_t status, char *out, unsigned n)
{
    static const char TEXT[] FLASH = "ok\0"
                                     "truncated\0"
                                     "not a calibration set (magic)\0"
                                     "unsupported format version\0"
                                     "reserved flags not 0\0"
                                     "a table needs 2 to 16 knots\0"
                                     "length does not match the knot counts\0"
                                     "CRC mismatch: damaged\0"
                                     "a number is not finite\0"
                                     "knot x not strictly increasing\0"
                                     "flat table\0"
                                     "not strictly monotone\0"
                                     "knot slope would break monotonicity\0"
                                     "ESC endpoints or deadband out of range\0"
                                     "KV out of range\0"
                                     "throttle curve must run from (0,0) to (1,1)\0"
                                     "gimbal rate tables must meet at rate 0, turning the same way\0"
                                     "hold pulse outside the dead zone\0"
                                     "gimbal pulse outside 500..2500 us\0"
                                     "unknown";
    flash_pick(TEXT, status < CAL_ERRORS ? (unsigned)status : (unsigned)CAL_ERRORS, out, n);
}
