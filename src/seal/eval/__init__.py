"""The evaluation harness behind `seal eval`: which trials (`trials`), how one runs (`execute`),
where they run (`backends`), where results go (`store`), and the resumable loop (`runner`)."""
