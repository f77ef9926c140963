// Out-of-line anchor for the HAL interfaces' vtables (one translation unit owns them).
#include "hal.hpp"
