// Names and colours of change types and statuses, and an event's primary side (change.hpp).

#include "planesdf/change.hpp"

namespace planesdf {

const char* toString(ChangeType t) {
  switch (t) {
    case ChangeType::Added:
      return "added";
    case ChangeType::Removed:
      return "removed";
    case ChangeType::Moved:
      return "moved";
    case ChangeType::Replaced:
      return "replaced";
  }
  return "unknown";
}

const char* toString(ChangeStatus s) {
  switch (s) {
    case ChangeStatus::New:
      return "new";
    case ChangeStatus::Updated:
      return "updated";
    case ChangeStatus::Retracted:
      return "retracted";
  }
  return "unknown";
}

const ChangeRegion& ChangeEvent::primary() const {
  return type == ChangeType::Removed || current.empty() ? reference : current;
}

std::array<std::uint8_t, 3> changeColor(ChangeType t) {
  switch (t) {
    case ChangeType::Added:
      return {230, 40, 40};
    case ChangeType::Removed:
      return {40, 90, 230};
    case ChangeType::Moved:
      return {240, 220, 30};
    case ChangeType::Replaced:
      return {220, 40, 220};
  }
  return {255, 255, 255};
}

}  // namespace planesdf
