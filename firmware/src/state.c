/* state.c - the board's state transitions (see state.h). */
#include "state.h"

static transition_t result(uint8_t state, uint8_t refused)
{
    transition_t t = {state, refused};
    return t;
}

transition_t state_transition(uint8_t state, uint8_t event, uint8_t power_ok)
{
    switch (event) {
    case EVENT_RESET:
        return result(BOARD_STATE_BOOT, 0);
    case EVENT_HELLO:
        return result(BOARD_STATE_DISARMED, 0);
    case EVENT_LINK_LOST:
        return result(state == BOARD_STATE_ARMED ? BOARD_STATE_FAILSAFE : state, 0);
    default:
        break;
    }
    if (state == BOARD_STATE_BOOT)
        return result(state, NACK_REASON_BAD_STATE);
    switch (event) {
    case EVENT_ARM:
        return power_ok ? result(BOARD_STATE_ARMED, 0) : result(state, NACK_REASON_POWER);
    case EVENT_DISARM:
        return result(BOARD_STATE_DISARMED, 0);
    case EVENT_SET_MODE:
        return result(state, state == BOARD_STATE_DISARMED ? 0 : NACK_REASON_BAD_STATE);
    default:
        return result(state, NACK_REASON_UNSUPPORTED);
    }
}
