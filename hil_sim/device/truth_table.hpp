// The sensor truth the simulated device's BNO055 and LIDAR-Lite see, read from the CSV that
// `icgt sim` writes (hil_sim/README.md, "Sensor truth table") and interpolated in time.
#pragma once

#include <array>
#include <string>
#include <vector>

namespace icgt::sim {

struct TruthRow {
  double tau_s = 0.0;
  std::array<double, 4> quat_wxyz{1.0, 0.0, 0.0, 0.0};
  std::array<double, 3> gyro_rad_s{};
  std::array<double, 3> accel_m_s2{0.0, 0.0, 9.80665};
  std::array<double, 3> lin_accel_m_s2{};
  double range_cm = 0.0;
  bool range_valid = false;
};

class TruthTable {
 public:
  // Reads the CSV; on failure returns false and sets error to a message naming the line.
  [[nodiscard]] bool load(const std::string& path, std::string& error);
  // A table with one constant row (no file): the device at rest, level, 5 m from a wall.
  void set_constant(const TruthRow& row) { rows_.assign(1, row); }

  // Linear interpolation between the rows around tau_s (the quaternion by normalised lerp
  // along the shorter arc); held constant outside the table.
  [[nodiscard]] TruthRow at(double tau_s) const;
  [[nodiscard]] std::size_t size() const { return rows_.size(); }

 private:
  std::vector<TruthRow> rows_;
};

}  // namespace icgt::sim
