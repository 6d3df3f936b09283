// The k nearest found so far by the neighbour searches (pixel_neighbours.h, point_neighbours.h):
// (squared distance, index) pairs kept ascending, equal distances in ascending index.
#ifndef BIMCAP_RASTER_K_BEST_H_
#define BIMCAP_RASTER_K_BEST_H_

#include <algorithm>
#include <cstdint>
#include <vector>

namespace bimcap::raster {

class KBest {
 public:
  explicit KBest(int k) : k_(k) { items_.reserve(static_cast<size_t>(k) + 1); }

  bool full() const { return static_cast<int>(items_.size()) == k_; }
  // The k-th distance (only when full()).
  double worst() const { return items_.back().d2; }

  void Offer(double d2, int64_t index) {
    const Item item{d2, index};
    if (full() && !Less(item, items_.back())) return;
    items_.insert(std::upper_bound(items_.begin(), items_.end(), item, Less), item);
    if (static_cast<int>(items_.size()) > k_) items_.pop_back();
  }

  // The indices, nearest first.
  void Write(int64_t* out) const {
    for (size_t i = 0; i < items_.size(); ++i) out[i] = items_[i].index;
  }

  void Clear() { items_.clear(); }

 private:
  struct Item {
    double d2;
    int64_t index;
  };
  static bool Less(const Item& a, const Item& b) {
    return a.d2 < b.d2 || (a.d2 == b.d2 && a.index < b.index);
  }
  int k_;
  std::vector<Item> items_;
};

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_K_BEST_H_
