/* power.c - the staged power manager and the state-of-charge estimate (see power.h). */
#include "power.h"

#include "board_gen.h"
#include "flash.h"
#include "protocol_gen.h"

void power_reset(power_manager_t *pm)
{
    pm->primed = 0;
    pm->filtered_v_cell = 0.0f;
    pm->stage = POWER_STATE_NORMAL;
}

static uint8_t stage_of(const power_params_t *p, uint8_t current, float v)
{
    const float levels[3] = {p->shed_v_cell, p->limit_v_cell, p->warn_v_cell};
    const uint8_t stages[3] = {POWER_STATE_SHED, POWER_STATE_LIMIT, POWER_STATE_WARN};
    if (current == POWER_STATE_BROWN_OUT)
        current = POWER_STATE_NORMAL;
    for (uint8_t i = 0; i < 3; i++) {
        /* Enter below the level; stay in a stage already reached until hysteresis above it. */
        if (v < levels[i] || (current >= stages[i] && v < levels[i] + p->hysteresis_v_cell))
            return stages[i];
    }
    return POWER_STATE_NORMAL;
}

uint8_t power_update(power_manager_t *pm, const power_params_t *p, float battery_v)
{
    float v_cell = battery_v / (float)p->cells;
    if (!pm->primed) {
        pm->filtered_v_cell = v_cell;
        pm->primed = 1;
    } else {
        pm->filtered_v_cell += (v_cell - pm->filtered_v_cell) * p->alpha;
    }
    pm->stage = stage_of(p, pm->stage, pm->filtered_v_cell);
    return pm->stage;
}

float power_full_cell_v(void)
{
    static const float VOLTS[LIPO_OCV_POINTS] FLASH = LIPO_OCV_V;
    float full;
    flash_read(&full, &VOLTS[LIPO_OCV_POINTS - 1], sizeof full);
    return full;
}

float power_soc(float v_cell)
{
    static const float SOC[LIPO_OCV_POINTS] FLASH = LIPO_OCV_SOC;
    static const float VOLTS[LIPO_OCV_POINTS] FLASH = LIPO_OCV_V;
    float soc[LIPO_OCV_POINTS], volts[LIPO_OCV_POINTS];
    flash_read(soc, SOC, sizeof soc);
    flash_read(volts, VOLTS, sizeof volts);
    if (v_cell <= volts[0])
        return soc[0];
    for (uint8_t i = 1; i < LIPO_OCV_POINTS; i++) {
        if (v_cell <= volts[i]) {
            float span = volts[i] - volts[i - 1];
            if (span <= 0.0f)
                return soc[i];
            return soc[i - 1] + (soc[i] - soc[i - 1]) * (v_cell - volts[i - 1]) / span;
        }
    }
    return soc[LIPO_OCV_POINTS - 1];
}
