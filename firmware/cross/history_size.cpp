// Not linked: compiled for each CPU so build.sh can read the history's size for that board
// (objcopy of this one constant) and check it against the board's RAM budget.
#include "core/history.hpp"

extern "C" {
extern const uint32_t icgt_history_bytes;
extern const uint32_t icgt_history_event_slots;
const uint32_t icgt_history_bytes = icgt::core::History::bytes();
const uint32_t icgt_history_event_slots = icgt::core::History::kSizes.event_slots;
}
