// main() of the firmware's host unit tests under `pio test -e native` (PlatformIO runs the
// test folders named test_*; this one holds only the entry point, the tests themselves are
// the component folders next to it, compiled in through test_build_src and build_src_filter).
// CMake and `pio run -e native -t exec` link GoogleTest's own gtest_main instead.
#include <gtest/gtest.h>

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
